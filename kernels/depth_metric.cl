/* depth_metric.cl: the metric depth term (docs/method.md §10). The depth prior of a training view
 * (the built-in stereo prior: metric depth in scene units, with a confidence) pins the rendered
 * depth in absolute terms, where DNGaussian's depth loss (depth_loss.cl) compares patch-normalised
 * depths only:
 *     L = w / S * sum_p c_p |D_p - a_p t_p| / t_p,      S = sum of c_p over the valid pixels
 * D the rendered depth (sum of z alpha T, rasterize.cl), a the rendered alpha, held constant (no
 * gradient: where the render covers the pixel, a_p t_p is the depth D would have with the surface
 * at the target), t the target depth, c the per-pixel weight (the prior's confidence). A pixel is
 * valid where c_p > 0 and t_p is positive and finite; the others add nothing.
 *     dL/dD_p = (w / S) c_p sign(D_p - a_p t_p) / t_p      (0 at D_p = a_p t_p, and for NaN D_p)
 * The host computes scale = float32(w / S) once per view (S in float64).
 * Twin: reings.backends.reference_loss.depth_metric_fwd_bwd (float64); the host trainer mirrors
 * these float32 operations in this order, so on PoCL both trainers give the same bits.
 *
 * depth_metric_grad  global (n): v_depth = g, or v_depth += g with accumulate != 0 (the term joins
 *                    another depth cotangent, e.g. the view_warp term's, in one backward)
 * depth_metric_rows  global (H): per row the float32 sum of c |D - a t| / t over its valid pixels,
 *                    left to right (a non-finite D - a t adds nothing); the host sums the rows
 *                    in float64 and multiplies by scale
 *                    (only when the loss is read: logging iterations)
 */
#pragma OPENCL FP_CONTRACT OFF

inline int dm_valid(const float c, const float t) { return c > 0.0f && t > 0.0f && isfinite(t); }

__kernel void depth_metric_grad(const int n, const float scale, const int accumulate,
                                __global const float *depth,   /* [H, W] rendered depth */
                                __global const float *alpha,   /* [H, W] rendered alpha */
                                __global const float *target,  /* [H, W] metric depth target */
                                __global const float *wt,      /* [H, W] per-pixel weight */
                                __global float *v_depth)       /* [H, W] out (or += ) */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    const float t = target[i], c = wt[i];
    float g = 0.0f;
    if (dm_valid(c, t)) {
        const float r = depth[i] - alpha[i] * t;
        const float s = r > 0.0f ? 1.0f : (r < 0.0f ? -1.0f : 0.0f);
        g = scale * c * s / t;
    }
    v_depth[i] = accumulate ? v_depth[i] + g : g;
}

__kernel void depth_metric_rows(const int width, const int height,
                                __global const float *depth, __global const float *alpha,
                                __global const float *target, __global const float *wt,
                                __global float *rows)          /* [H] out */
{
    const int y = get_global_id(0);
    if (!(y < height)) return;
    float acc = 0.0f;
    for (int x = 0; x < width; ++x) {
        const int i = y * width + x;
        const float t = target[i], c = wt[i];
        if (dm_valid(c, t)) {
            const float r = depth[i] - alpha[i] * t;
            if (isfinite(r)) acc += c * fabs(r) / t;
        }
    }
    rows[y] = acc;
}
