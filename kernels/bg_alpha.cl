/* bg_alpha.cl: the gradient of DNGaussian's DTU background term mean(alpha^2) over the background
   pixels (reings.background.dark_background_mask of the training image): the device trainer's
   `bg_alpha` (reings/backends/opencl/trainer.py). Twin: reference_loss.bg_alpha_fwd_bwd (float64);
   here v_alpha = scale * alpha on background pixels, 0 elsewhere, with scale = float32(2 / count)
   from the host: one float multiply per pixel. */
#pragma OPENCL FP_CONTRACT OFF

__kernel void bg_alpha_grad(const int n, const float scale,
                            __global const float *alpha,  /* [H, W] rendered alpha */
                            __global const float *mask,   /* [H, W] 1 = background, 0 = not */
                            __global float *v_alpha)      /* [H, W] out */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    v_alpha[i] = mask[i] != 0.0f ? scale * alpha[i] : 0.0f;
}
