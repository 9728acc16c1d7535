/* block_mean.cl: the mean over s x s blocks of an image, and its adjoint (the view_warp term at 1/s,
 * LossConfig.view_warp_scale, docs/binocular.md §4.5).
 *
 * An image a [H, W, C] (row-major, C channels) pools to out [Ho, Wo, C], Ho = H / s, Wo = W / s
 * (integer division: the last rows and columns that do not fill a block are dropped; pixel (i, j)
 * covers a's pixels [s i, s i + s) x [s j, s j + s), reings.train.depth_pass_camera's camera):
 *     out(i, j, c) = (a's s^2 values of the block added row by row, left to right, to 0.0f) * inv
 * inv = float32(1 / s^2) from the host (exact for s = 2, 4). The adjoint of that linear map:
 *     v_full(y, x, c) = v(y / s, x / s, c) * inv   for y < s Ho and x < s Wo, else 0
 * written, or added to v_full with accumulate != 0 (another term's cotangent).
 * Twin: reings.backends.reference_block_mean.block_mean_fwd / block_mean_bwd (float64); the host
 * trainer mirrors these float32 operations in this order (block_mean_f32, block_mean_bwd_f32), so on
 * PoCL both trainers give the same bits (no contraction: FP_CONTRACT OFF).
 *
 * block_mean_fwd  global (>= n = Ho Wo C): one output element per work-item
 * block_mean_bwd  global (>= n = H W C): one full-resolution element per work-item, reading its block's
 *                 one value (no scatter, no atomics)
 */
#pragma OPENCL FP_CONTRACT OFF

__kernel void block_mean_fwd(const int n, const int width, const int out_width, const int channels,
                             const int s, const float inv,
                             __global const float *a,   /* [H, W, C] */
                             __global float *out)       /* [Ho, Wo, C] */
{
    const int k = get_global_id(0);
    if (!(k < n)) return;
    const int p = k / channels, c = k - p * channels;  /* not %: Oclgrind cannot check LLVM's div/rem pair */
    const int i = p / out_width, j = p - i * out_width;
    float acc = 0.0f;
    for (int dy = 0; dy < s; ++dy) {
        const int row = ((s * i + dy) * width + s * j) * channels + c;
        for (int dx = 0; dx < s; ++dx) acc += a[row + dx * channels];
    }
    out[k] = acc * inv;
}

__kernel void block_mean_bwd(const int n, const int width, const int channels, const int s,
                             const int out_height, const int out_width, const float inv, const int accumulate,
                             __global const float *v,   /* [Ho, Wo, C] */
                             __global float *v_full)    /* [H, W, C] out (or += ) */
{
    const int k = get_global_id(0);
    if (!(k < n)) return;
    const int p = k / channels, c = k - p * channels;
    const int y = p / width, x = p - y * width;
    const int i = y / s, j = x / s;
    float g = 0.0f;
    if (i < out_height && j < out_width) g = v[(i * out_width + j) * channels + c] * inv;
    v_full[k] = accumulate ? v_full[k] + g : g;
}
