/* photometric.cl: the photometric loss  w_l1 * mean|x - y| + w_ssim * (1 - mean SSIM(x, y))  and its
 * gradient w.r.t. the rendered image x, as separable Gaussian-convolution passes.
 *
 * Must match reings.backends.reference_loss.{ssim_fwd_bwd, l1_fwd_bwd, photometric_fwd_bwd}
 * (tests/test_losses.py).  SSIM is 3DGS's: 11-tap Gaussian window, sigma 1.5 (taps passed in, the
 * normalised 1-D Gaussian), zero-padded 'same' convolution per channel, C1 = 0.01^2, C2 = 0.03^2.
 *
 * Images are [H, W, 3] float32 (RenderOutput.rgb layout); "planes" are [P, H, W, 3] stacks.
 * Pass order, one work-item per pixel (global size (W, H)), all channels in the work-item:
 *   ssim_hpass_fwd  x, y, x*x, y*y, x*y          -> conv along W   (h5)
 *   ssim_vpass_fwd  h5 -> conv along H -> mu_x, mu_y, E[xx], E[yy], E[xy] -> SSIM map and
 *                   w_ssim_grad * dS/d(mu_x, E[xx], E[xy])           (smap, d3)
 *   ssim_hpass_bwd  d3 -> conv along W (the zero-padded symmetric conv is self-adjoint)  (h3)
 *   ssim_vpass_bwd  h3 -> conv along H, combine with x, y and the L1 sign               (v_x)
 *   loss_row_sums   per-row sums of the SSIM map and |x - y| (one work-item per row; the host
 *                   adds the H partials in float64, so the result is deterministic)
 * Defines: none besides the capability defines.  Not handled: masks, other window sizes.
 */

#define SSIM_R 5                      /* window radius: 11 taps */
#define SSIM_C1 (0.01f * 0.01f)       /* 3DGS constants (data range 1) */
#define SSIM_C2 (0.03f * 0.03f)

__kernel void ssim_hpass_fwd(__global const float *x,     // [H, W, 3] rendered image
                             __global const float *y,     // [H, W, 3] ground truth
                             __constant float *taps,      // [11] normalised 1-D Gaussian
                             __global float *h5,          // [5, H, W, 3] conv_W of x, y, xx, yy, xy
                             const int W, const int H)
{
    const int i = get_global_id(0), j = get_global_id(1);
    if (!(i < W && j < H)) return;
    const int plane = H * W * 3;
    for (int c = 0; c < 3; ++c) {
        float sx = 0.0f, sy = 0.0f, sxx = 0.0f, syy = 0.0f, sxy = 0.0f;
        for (int k = -SSIM_R; k <= SSIM_R; ++k) {
            const int ii = i + k;
            if (ii < 0 || ii >= W) continue;  /* zero padding */
            const float w = taps[k + SSIM_R];
            const float a = x[(j * W + ii) * 3 + c], b = y[(j * W + ii) * 3 + c];
            sx += w * a; sy += w * b; sxx += w * a * a; syy += w * b * b; sxy += w * a * b;
        }
        const int o = (j * W + i) * 3 + c;
        h5[o] = sx; h5[plane + o] = sy; h5[2 * plane + o] = sxx; h5[3 * plane + o] = syy; h5[4 * plane + o] = sxy;
    }
}

__kernel void ssim_vpass_fwd(__global const float *h5,    // [5, H, W, 3] from ssim_hpass_fwd
                             __constant float *taps,      // [11]
                             __global float *smap,        // [H, W, 3] SSIM map
                             __global float *d3,          // [3, H, W, 3] w * dS/d(mu_x, E[xx], E[xy])
                             const float w_ssim_grad,     // dL/dS of one element: -w_ssim / (3 H W)
                             const int W, const int H)
{
    const int i = get_global_id(0), j = get_global_id(1);
    if (!(i < W && j < H)) return;
    const int plane = H * W * 3;
    for (int c = 0; c < 3; ++c) {
        float mx = 0.0f, my = 0.0f, exx = 0.0f, eyy = 0.0f, exy = 0.0f;
        for (int k = -SSIM_R; k <= SSIM_R; ++k) {
            const int jj = j + k;
            if (jj < 0 || jj >= H) continue;
            const float w = taps[k + SSIM_R];
            const int o = (jj * W + i) * 3 + c;
            mx += w * h5[o]; my += w * h5[plane + o]; exx += w * h5[2 * plane + o];
            eyy += w * h5[3 * plane + o]; exy += w * h5[4 * plane + o];
        }
        const float sx = exx - mx * mx, sy = eyy - my * my, sxy = exy - mx * my;
        const float a1 = 2.0f * mx * my + SSIM_C1, a2 = 2.0f * sxy + SSIM_C2;
        const float b1 = mx * mx + my * my + SSIM_C1, b2 = sx + sy + SSIM_C2;
        const float inv_d = 1.0f / (b1 * b2);  /* b1 >= C1 > 0; b2 > 0 up to rounding, as in 3DGS */
        const float s = a1 * a2 * inv_d;
        const int o = (j * W + i) * 3 + c;
        smap[o] = s;
        d3[o] = w_ssim_grad * (2.0f * my * (a2 - a1) - s * 2.0f * mx * (b2 - b1)) * inv_d;  /* d/d mu_x */
        d3[plane + o] = w_ssim_grad * (-s * b1 * inv_d);                                    /* d/d E[xx] */
        d3[2 * plane + o] = w_ssim_grad * (2.0f * a1 * inv_d);                              /* d/d E[xy] */
    }
}

__kernel void ssim_hpass_bwd(__global const float *d3,    // [3, H, W, 3]
                             __constant float *taps,      // [11]
                             __global float *h3,          // [3, H, W, 3] conv_W of d3
                             const int W, const int H)
{
    const int i = get_global_id(0), j = get_global_id(1);
    if (!(i < W && j < H)) return;
    const int plane = H * W * 3;
    for (int c = 0; c < 3; ++c) {
        float s0 = 0.0f, s1 = 0.0f, s2 = 0.0f;
        for (int k = -SSIM_R; k <= SSIM_R; ++k) {
            const int ii = i + k;
            if (ii < 0 || ii >= W) continue;
            const float w = taps[k + SSIM_R];
            const int o = (j * W + ii) * 3 + c;
            s0 += w * d3[o]; s1 += w * d3[plane + o]; s2 += w * d3[2 * plane + o];
        }
        const int o = (j * W + i) * 3 + c;
        h3[o] = s0; h3[plane + o] = s1; h3[2 * plane + o] = s2;
    }
}

__kernel void ssim_vpass_bwd(__global const float *h3,    // [3, H, W, 3] from ssim_hpass_bwd
                             __global const float *x,     // [H, W, 3]
                             __global const float *y,     // [H, W, 3]
                             __constant float *taps,      // [11]
                             __global float *v_x,         // [H, W, 3] dL/dx
                             const float w_l1_grad,       // dL/d|x-y| of one element: w_l1 / (3 H W)
                             const int W, const int H)
{
    const int i = get_global_id(0), j = get_global_id(1);
    if (!(i < W && j < H)) return;
    const int plane = H * W * 3;
    for (int c = 0; c < 3; ++c) {
        float g0 = 0.0f, g1 = 0.0f, g2 = 0.0f;
        for (int k = -SSIM_R; k <= SSIM_R; ++k) {
            const int jj = j + k;
            if (jj < 0 || jj >= H) continue;
            const float w = taps[k + SSIM_R];
            const int o = (jj * W + i) * 3 + c;
            g0 += w * h3[o]; g1 += w * h3[plane + o]; g2 += w * h3[2 * plane + o];
        }
        const int o = (j * W + i) * 3 + c;
        const float a = x[o], b = y[o];
        const float sgn = (a > b) ? 1.0f : ((a < b) ? -1.0f : 0.0f);  /* torch sign: 0 at ties */
        v_x[o] = g0 + 2.0f * a * g1 + b * g2 + w_l1_grad * sgn;
    }
}

__kernel void loss_row_sums(__global const float *smap,   // [H, W, 3]
                            __global const float *x,      // [H, W, 3]
                            __global const float *y,      // [H, W, 3]
                            __global float *partial,      // [H, 2] (sum SSIM, sum |x - y|) per row
                            const int W, const int H)
{
    const int j = get_global_id(0);
    if (!(j < H)) return;
    float ss = 0.0f, sl = 0.0f;
    for (int o = j * W * 3; o < (j + 1) * W * 3; ++o) {
        ss += smap[o];
        sl += fabs(x[o] - y[o]);
    }
    partial[2 * j] = ss;
    partial[2 * j + 1] = sl;
}
