/* view_warp.cl: the binocular view-consistency term (Han et al., NeurIPS 2024; docs/binocular.md)
 * and its gradients w.r.t. the virtual render AND the training view's rendered depth.
 *
 * Must match reings.backends.reference_view_warp (float64; its docstring has the formulas, the
 * authors' code lines are cited in docs/binocular.md). Per training pixel (x, y):
 *     d = neg_fb / (D + 1e-5)            neg_fb = -fx * b, b the virtual camera's x offset
 *     x0 = floor(d), c0 = x + x0, valid = 0 <= c0 <= W-2 (and D finite, |d| < W + 1)
 *     warped_c = w0 virt_c(y, c0) + w1 virt_c(y, c0+1),  w1 = d - x0, w0 = (x0 + 1) - d
 *     L = gl * sum |warped - gt| (valid pixels)  +  gs * sum_o wx|ex| + wy|ey|   (disparity smoothness)
 * with gl = weight / (3 H W) and gs = weight * smooth_weight / ((H-2)(W-2)) from the host (gs = 0
 * skips every smoothness computation). The warp moves pixels along rows only (rectified pair), so
 * row y of the virtual image receives gradient from row y of the training view alone.
 *
 * Kernels (images [H, W, 3] float32, depth [H, W] float32, row-major)
 *   view_warp_fwd       global (>= W, H): warped [H, W, 3] (0 where invalid) and valid [H, W]
 *                       (0/1). Diagnostics and tests; not needed by the training step.
 *   view_warp_edges     global (>= W, H): the image-edge weights of a training image, (wx, wy) per
 *                       interior pixel (0 off the interior) into edges [H, W, 2]. They depend on
 *                       the image alone: the host makes them once per training view (ViewWarpCL.
 *                       edges) and every view_warp_smooth of that view reads them (two exponentials
 *                       per pixel fewer per step: docs/perf_notes.md §32).
 *   view_warp_smooth    global (>= W, H), only when gs != 0, before view_warp_bwd_depth: per pixel o the
 *                       signed weights sxy(o) = (wx sign(ex), wy sign(ey)) and the term wx |ex| + wy |ey| into
 *                       pix_f[o, 1] (all 0 off the interior; wx, wy from view_warp_edges).
 *                       Stored once so that the depth gradient's stencil (sx at x +- 1, sy at
 *                       y +- 1) reads four numbers instead of recomputing 8 disparities and 4
 *                       exponentials per pixel (2.5x faster on PoCL at 504x378: docs/binocular.md).
 *   view_warp_bwd_depth global (>= W, H): per pixel v_depth (written, or added to with accumulate = 1;
 *                       0 where invalid), the gradient record of the virtual image (left tap column
 *                       c0, VW_INVALID if invalid; w0 g_c and w1 g_c) and pix_f[o, 0] = (|r0| + |r1|) + |r2|
 *                       (0 where invalid; pix_f[o, 1] = 0 when gs == 0).
 *   view_warp_rows      global (VW_WG, H), local (VW_WG, 1): one work-group per row, lanes striding over x
 *                       (fixed tree): row_f[y] = the row's sums of pix_f[., 0] and pix_f[., 1], row_i[y] =
 *                       (valid count, min x0, max x0), x0 = c0 - x over the valid pixels. Before
 *                       view_warp_bwd_virt's gather schedule (its windows); on the CPU schedule only when
 *                       the loss is read (the host's read_stats). Until 2026-11-29 bwd_depth and smooth
 *                       were per-row kernels making these sums in every step: per pixel they run 2x
 *                       faster on PoCL, with no reduction in the step (docs/perf_notes.md §35).
 *   view_warp_bwd_virt  v_virt [H, W, 3] (overwritten) from the records; two schedules giving the
 *                       same bits:
 *                       REINGS_CPU_SCHEDULE=1: global (H), one work-item per row scatters the row's
 *                         records in ascending x into the zeroed row;
 *                       otherwise global (>= W, H): one work-item per virtual pixel u gathers the
 *                         records of the x with c0 = u or c0 + 1 = u, in ascending x, from the
 *                         window x in [u - 1 - max x0, u - min x0] (the row's disparity range).
 *                       Either way each v_virt element is 0.0f plus its contributions in
 *                       ascending x, so the result is deterministic and schedule-independent.
 *   view_warp_total     global (VW_WG), local (VW_WG): one work-group sums view_warp_rows' records with
 *                       lane-strided partials and a fixed tree into total[3] = (sum |r|, smooth
 *                       sum, valid count as float: exact below 2^24 pixels). Launched only when
 *                       the host reads the loss.
 *
 * Determinism without float atomics: every reduction is a fixed-order sum (lane-strided partials,
 * then a fixed tree); the one many-to-one map (the warp's scatter into the virtual image) goes
 * through a per-pixel record buffer reduced per destination in ascending source order. Why not
 * atomics: float atomic adds make the sum order depend on scheduling (a run would not repeat
 * bit for bit), and pip PoCL has no native float atomic at all.
 * Why the gather window: the records of one virtual pixel u come only from sources x with
 * x + x0(x) in {u - 1, u}, so x lies in [u - 1 - max x0, u - min x0]; its width is the row's
 * disparity range + 2 (tens of pixels for a real scene; W at worst), and the gather needs no
 * sort and no local memory.
 *
 * Defines
 *   VW_WG   work-group size of the per-row kernel view_warp_rows and of view_warp_total, a power of two (host: 1 on
 *           CPU devices, 64 on GPUs; 64 here by default)
 * Not clamped: a depth below -1e-5 gives a disparity of the other sign and exactly -1e-5 an
 * infinite one; both are used (or masked) as the formula says, like the authors' code. No occlusion
 * test either (the authors have none): a training pixel hidden in the virtual view is compared too.
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#ifndef VW_WG
#define VW_WG 64
#endif

#define VW_DEPTH_EPS 1e-5f   /* disparity = f b / (D + 1e-5) (authors' train.py) */
#define VW_EDGE_SCALE 0.33f  /* image-edge weight exp(-0.33 |dI|) (authors' SmoothLoss) */
#define VW_INVALID (-2)      /* record tap of an invalid pixel: never u nor u - 1 for u >= 0 */

/* The disparity d at column x of a row and its left tap. Returns 1 if both taps lie in the row.
 * Guards are positive so NaN fails them: a non-finite D, or |d| >= W + 1 (whose taps are off the
 * row anyway, and whose floor could overflow an int), is invalid. */
static int vw_tap(const float D, const float neg_fb, const int x, const int W, float *d, float *x0f, int *c0)
{
    const float dd = neg_fb / (D + VW_DEPTH_EPS);
    *d = dd;
    *x0f = 0.0f;
    *c0 = VW_INVALID;
    if (!(ISFINITE1(D) && FABS1(dd) < (float)W + 1.0f)) return 0;
    const float f = FLOOR1(dd);
    const int c = x + (int)f;
    *x0f = f;
    *c0 = c;
    return c >= 0 && c + 1 < W;
}

/* p = valid ? d : 0 (the authors' disparity * mask) at (x, y). */
static float vw_p(__global const float *depth, const float neg_fb, const int x, const int y, const int W)
{
    float d, f;
    int c;
    return vw_tap(depth[y * W + x], neg_fb, x, W, &d, &f, &c) ? d : 0.0f;
}

/* S = the channel sum of gt at (x, y). */
static float vw_s(__global const float *gt, const int x, const int y, const int W)
{
    const int o = 3 * (y * W + x);
    return gt[o] + gt[o + 1] + gt[o + 2];
}

static float vw_sign(const float v)
{
    return v > 0.0f ? 1.0f : (v < 0.0f ? -1.0f : 0.0f);  /* torch: abs'(0) = 0 */
}

static int vw_interior(const int x, const int y, const int W, const int H)
{
    return x >= 1 && x <= W - 2 && y >= 1 && y <= H - 2;
}

/* At an interior o = (x, y): the smoothness term wx |ex| + wy |ey| (returned) and the signed
 * weights wx sign(ex), wy sign(ey) that its gradient needs (into *sx, *sy); (wx, wy) = edges[o]. */
static float vw_smooth_at(__global const float *depth, __global const float *edges, const float neg_fb,
                          const int x, const int y, const int W, float *sx, float *sy)
{
    const float ex = 0.5f * (vw_p(depth, neg_fb, x + 1, y, W) - vw_p(depth, neg_fb, x - 1, y, W));
    const float ey = 0.5f * (vw_p(depth, neg_fb, x, y + 1, W) - vw_p(depth, neg_fb, x, y - 1, W));
    const float wx = edges[2 * (y * W + x)], wy = edges[2 * (y * W + x) + 1];
    *sx = wx * vw_sign(ex);
    *sy = wy * vw_sign(ey);
    return wx * FABS1(ex) + wy * FABS1(ey);
}

__kernel void view_warp_fwd(__global const float *virt,   // [H, W, 3] virtual render
                            __global const float *depth,  // [H, W] training view's rendered depth
                            __global float *warped,       // [H, W, 3] virt warped into the training view (0: invalid)
                            __global float *valid,        // [H, W] 1 / 0
                            const float neg_fb,           // -fx * b (pixels * depth units)
                            const int W, const int H)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (!(x < W && y < H)) return;
    const int p = y * W + x;
    float d, x0f;
    int c0;
    const int ok = vw_tap(depth[p], neg_fb, x, W, &d, &x0f, &c0);
    for (int c = 0; c < 3; ++c) {
        float v = 0.0f;
        if (ok) {
            const float w1 = d - x0f, w0 = (x0f + 1.0f) - d;
            v = w0 * virt[3 * (y * W + c0) + c] + w1 * virt[3 * (y * W + c0 + 1) + c];
        }
        warped[3 * p + c] = v;
    }
    valid[p] = ok ? 1.0f : 0.0f;
}

/* The edge weights (wx, wy) = exp(-0.33 |dI|) of the training image's channel sums' central
 * differences at interior pixels, 0 elsewhere (the authors' SmoothLoss). */
__kernel void view_warp_edges(__global const float *gt,  // [H, W, 3] training image
                              __global float *edges,     // [H, W, 2]
                              const int W, const int H)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (!(x < W && y < H)) return;
    float wx = 0.0f, wy = 0.0f;
    if (vw_interior(x, y, W, H)) {
        wx = exp(-VW_EDGE_SCALE * fabs(0.5f * (vw_s(gt, x + 1, y, W) - vw_s(gt, x - 1, y, W))));
        wy = exp(-VW_EDGE_SCALE * fabs(0.5f * (vw_s(gt, x, y + 1, W) - vw_s(gt, x, y - 1, W))));
    }
    edges[2 * (y * W + x)] = wx;
    edges[2 * (y * W + x) + 1] = wy;
}

__kernel void view_warp_smooth(__global const float *depth,  // [H, W] training view's rendered depth
                               __global const float *edges,  // [H, W, 2] view_warp_edges of the training image
                               __global float *sxy,          // [H, W, 2] (wx sign(ex), wy sign(ey)); 0 off the interior
                               __global float *pix_f,        // [H, W, 2] writes [p, 1]: the pixel's smoothness term
                               const float neg_fb, const int W, const int H)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (!(x < W && y < H)) return;
    const int p = y * W + x;
    float sx = 0.0f, sy = 0.0f, t = 0.0f;
    if (vw_interior(x, y, W, H)) t = vw_smooth_at(depth, edges, neg_fb, x, y, W, &sx, &sy);
    sxy[2 * p] = sx;
    sxy[2 * p + 1] = sy;
    pix_f[2 * p + 1] = t;
}

__kernel void view_warp_bwd_depth(__global const float *virt,   // [H, W, 3] virtual render
                                  __global const float *depth,  // [H, W] training view's rendered depth
                                  __global const float *gt,     // [H, W, 3] training image
                                  __global const float *sxy,    // [H, W, 2] from view_warp_smooth (read if gs != 0)
                                  __global float *v_depth,      // [H, W] dL/d depth (written, or added to)
                                  __global int *rec_tap,        // [H, W] left tap column c0, VW_INVALID if invalid
                                  __global float *rec_g,        // [H, W, 6] (w0 g_c, w1 g_c), written where valid
                                  __global float *pix_f,        // [H, W, 2] writes [p, 0] = (|r0| + |r1|) + |r2| (0 if invalid); [p, 1] = 0 if gs == 0
                                  const float neg_fb,           // -fx * b
                                  const float gl,               // weight / (3 H W)
                                  const float gs,               // weight * smooth_weight / ((H-2)(W-2)); 0: no smoothness
                                  const int accumulate,         // 1: v_depth += ..., 0: v_depth = ...
                                  const int W, const int H)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (!(x < W && y < H)) return;
    const int p = y * W + x;
    const float D = depth[p];
    float d, x0f;
    int c0;
    const int ok = vw_tap(D, neg_fb, x, W, &d, &x0f, &c0);
    float gd = 0.0f;  /* dL/dd */
    float l1 = 0.0f;
    if (ok) {
        const float w1 = d - x0f, w0 = (x0f + 1.0f) - d;
        for (int c = 0; c < 3; ++c) {
            const float a = virt[3 * (y * W + c0) + c], b = virt[3 * (y * W + c0 + 1) + c];
            const float r = (w0 * a + w1 * b) - gt[3 * p + c];
            const float g = gl * vw_sign(r);
            l1 += FABS1(r);
            gd += g * (b - a);
            rec_g[6 * p + c] = w0 * g;
            rec_g[6 * p + 3 + c] = w1 * g;
        }
    }
    rec_tap[p] = ok ? c0 : VW_INVALID;
    if (ok && gs != 0.0f) {  /* dS/dp = (sx(x-1) - sx(x+1) + sy(y-1) - sy(y+1)) / 2 */
        const float sxl = x > 0 ? sxy[2 * (p - 1)] : 0.0f, sxr = x + 1 < W ? sxy[2 * (p + 1)] : 0.0f;
        const float syu = y > 0 ? sxy[2 * (p - W) + 1] : 0.0f, syd = y + 1 < H ? sxy[2 * (p + W) + 1] : 0.0f;
        gd += gs * (0.5f * ((sxl - sxr) + (syu - syd)));
    }
    const float v = ok ? gd * (-d / (D + VW_DEPTH_EPS)) : 0.0f;
    v_depth[p] = accumulate ? v_depth[p] + v : v;
    pix_f[2 * p] = l1;
    if (gs == 0.0f) pix_f[2 * p + 1] = 0.0f;
}

__kernel void view_warp_rows(__global const float *pix_f,  // [H, W, 2] from view_warp_bwd_depth / view_warp_smooth
                             __global const int *rec_tap,  // [H, W] from view_warp_bwd_depth
                             __global float *row_f,        // [H, 2] the row's sums of pix_f[., 0], pix_f[., 1]
                             __global int *row_i,          // [H, 3] (valid count, min x0, max x0) of the row
                             const int W, const int H)
{
    __local float s_l1[VW_WG], s_sm[VW_WG];
    __local int s_n[VW_WG], s_lo[VW_WG], s_hi[VW_WG];
    const int lane = get_local_id(0), y = get_group_id(1);
    float a = 0.0f, b = 0.0f;
    int n = 0, lo = W + 1, hi = -(W + 1);  /* empty row: the gather window [u-1-hi, u-lo] is empty */
    if (y < H) {
        for (int x = lane; x < W; x += VW_WG) {
            const int p = y * W + x, c = rec_tap[p];
            a += pix_f[2 * p];
            b += pix_f[2 * p + 1];
            if (c != VW_INVALID) {  /* x0 = c0 - x */
                n += 1;
                lo = min(lo, c - x);
                hi = max(hi, c - x);
            }
        }
    }
    s_l1[lane] = a;
    s_sm[lane] = b;
    s_n[lane] = n;
    s_lo[lane] = lo;
    s_hi[lane] = hi;
    for (int off = VW_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lane < off) {
            s_l1[lane] += s_l1[lane + off];
            s_sm[lane] += s_sm[lane + off];
            s_n[lane] += s_n[lane + off];
            s_lo[lane] = min(s_lo[lane], s_lo[lane + off]);
            s_hi[lane] = max(s_hi[lane], s_hi[lane + off]);
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lane == 0 && y < H) {
        row_f[2 * y] = s_l1[0];
        row_f[2 * y + 1] = s_sm[0];
        row_i[3 * y] = s_n[0];
        row_i[3 * y + 1] = s_lo[0];
        row_i[3 * y + 2] = s_hi[0];
    }
}

__kernel void view_warp_bwd_virt(__global const int *rec_tap,  // [H, W] from view_warp_bwd_depth
                                 __global const float *rec_g,  // [H, W, 6]
                                 __global const int *row_i,    // [H, 3] (count, min x0, max x0)
                                 __global float *v_virt,       // [H, W, 3] dL/d virt (overwritten)
                                 const int W, const int H)
{
#if REINGS_CPU_SCHEDULE
    const int y = get_global_id(0);
    if (!(y < H)) return;
    __global float *row = v_virt + 3 * y * W;
    for (int o = 0; o < 3 * W; ++o) row[o] = 0.0f;
    for (int x = 0; x < W; ++x) {  /* ascending x: each destination gets its sources in order */
        const int p = y * W + x, c = rec_tap[p];
        if (c >= 0) {
            for (int k = 0; k < 3; ++k) {
                row[3 * c + k] += rec_g[6 * p + k];
                row[3 * (c + 1) + k] += rec_g[6 * p + 3 + k];
            }
        }
    }
#else
    const int u = get_global_id(0), y = get_global_id(1);
    if (!(u < W && y < H)) return;
    const int lo = max(0, u - 1 - row_i[3 * y + 2]), hi = min(W - 1, u - row_i[3 * y + 1]);
    float a0 = 0.0f, a1 = 0.0f, a2 = 0.0f;
    for (int x = lo; x <= hi; ++x) {  /* ascending x, as the row scatter */
        const int p = y * W + x, c = rec_tap[p];
        if (c == u) {
            a0 += rec_g[6 * p]; a1 += rec_g[6 * p + 1]; a2 += rec_g[6 * p + 2];
        } else if (c + 1 == u) {
            a0 += rec_g[6 * p + 3]; a1 += rec_g[6 * p + 4]; a2 += rec_g[6 * p + 5];
        }
    }
    const int o = 3 * (y * W + u);
    v_virt[o] = a0;
    v_virt[o + 1] = a1;
    v_virt[o + 2] = a2;
#endif
}

__kernel void view_warp_total(__global const float *row_f,  // [H, 2]
                              __global const int *row_i,    // [H, 3]
                              __global float *total,        // [3] (sum |r|, smoothness sum, valid count)
                              const int H)
{
    __local float s_l1[VW_WG], s_sm[VW_WG];
    __local int s_n[VW_WG];
    const int lane = get_local_id(0);
    float a = 0.0f, b = 0.0f;
    int n = 0;
    for (int y = lane; y < H; y += VW_WG) {
        a += row_f[2 * y];
        b += row_f[2 * y + 1];
        n += row_i[3 * y];
    }
    s_l1[lane] = a;
    s_sm[lane] = b;
    s_n[lane] = n;
    for (int off = VW_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lane < off) {
            s_l1[lane] += s_l1[lane + off];
            s_sm[lane] += s_sm[lane + off];
            s_n[lane] += s_n[lane + off];
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lane == 0) {
        total[0] = s_l1[0];
        total[1] = s_sm[0];
        total[2] = (float)s_n[0];
    }
}
