/* l1.cl: the L1-only photometric loss  w_l1 * mean|x - y|  and its gradient w.r.t. the rendered
 * image x, without any SSIM pass (the device engine's photometric pass when w_ssim == 0, and the
 * gsplat-comparable training step of bench/peer_step.py).
 *
 * Must match reings.backends.reference_loss.l1_fwd_bwd / loss.cl's L1 term: v_x = w_l1_grad *
 * sign(x - y) with torch's sign (0 at ties), w_l1_grad = float32(w_l1 / (3 H W)) -- bit-identical to
 * loss.cl's ssim_vpass_bwd with w_ssim = 0 (its SSIM terms are then exact zeros).
 *
 * Kernels (images [H, W, 3] float32, flat rows of 3W floats)
 *   l1_rows   global (L1_WG, H), local (L1_WG, 1): one work-group per image row writes v_x for the
 *             row and row_sums[j] = sum |x - y| over the row (lane-strided partials, then a fixed
 *             tree in local memory: deterministic).
 *   l1_total  global (L1_WG), local (L1_WG): one work-group sums the H row sums the same way into
 *             total[0] (float32). The loss is w_l1 * total[0] / (3 H W) (host, one scalar read).
 * Defines
 *   L1_WG     work-group size, a power of two (default 64; the host picks 1 on CPU devices).
 */

#ifndef L1_WG
#define L1_WG 64
#endif

static void l1_tree(__local float *s, const int lane)
{
    for (int off = L1_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lane < off) s[lane] += s[lane + off];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}

__kernel void l1_rows(__global const float *x,      // [H, W, 3] rendered image
                      __global const float *y,      // [H, W, 3] ground truth
                      __global float *v_x,          // [H, W, 3] dL/dx
                      __global float *row_sums,     // [H] sum |x - y| per row
                      const float w_l1_grad,        // dL/d|x-y| of one element: w_l1 / (3 H W)
                      const int row_len,            // 3 W
                      const int H)
{
    __local float s[L1_WG];
    const int lane = get_local_id(0), j = get_group_id(1);
    float acc = 0.0f;
    if (j < H) {
        const int base = j * row_len;
        for (int o = base + lane; o < base + row_len; o += L1_WG) {
            const float a = x[o], b = y[o];
            const float sgn = (a > b) ? 1.0f : ((a < b) ? -1.0f : 0.0f);  /* torch sign: 0 at ties */
            v_x[o] = w_l1_grad * sgn;
            acc += fabs(a - b);
        }
    }
    s[lane] = acc;
    l1_tree(s, lane);
    if (lane == 0 && j < H) row_sums[j] = s[0];
}

__kernel void l1_total(__global const float *row_sums,  // [H]
                       __global float *total,           // [1]
                       const int H)
{
    __local float s[L1_WG];
    const int lane = get_local_id(0);
    float acc = 0.0f;
    for (int j = lane; j < H; j += L1_WG) acc += row_sums[j];
    s[lane] = acc;
    l1_tree(s, lane);
    if (lane == 0) total[0] = s[0];
}
