/* grad_add.cl: dst[i] += src[i] over n floats: the gradients of a second backward added into those
   of the first (the device trainer's `backward(..., into=held)`, reings/backends/opencl/trainer.py:
   the photometric pass with the view_warp term backpropagates the training render and the virtual
   render and steps once). Twin: reference_state.grad_add (numpy float32 `+=`: one IEEE add per
   element, so the bits are the same). */
#pragma OPENCL FP_CONTRACT OFF

__kernel void grad_add(const uint n,
                       __global float *dst,        /* [n] += */
                       __global const float *src)  /* [n] */
{
    const uint i = get_global_id(0);
    if (!(i < n)) return;
    dst[i] = dst[i] + src[i];
}
