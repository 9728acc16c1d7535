/* grad_add.cl: dst[i] += src[i]: the gradients of a later backward added into those of the first (the
   device trainer's `backward(..., into=held)`, reings/backends/opencl/trainer.py: the photometric pass
   with the shared soft depth term or the view_warp term backpropagates the training render, then the
   soft term's records and the virtual render, and steps once). Twin: reference_state.grad_add (numpy
   float32 `+=`: one IEEE add per element, so the bits are the same).

   grad_add_multi: up to five (n, dst, src) slots in one launch (the fields of one backward: means,
   quats, log_scales, opacity_logits, sh), over max(n_k) work-items; an unused slot has n = 0. Every
   element gets the one add. */
#pragma OPENCL FP_CONTRACT OFF

#define GA_SLOT(k) const uint n##k, __global float *d##k, __global const float *s##k
#define GA_ADD(k) if (i < n##k) d##k[i] = d##k[i] + s##k[i]

__kernel void grad_add_multi(GA_SLOT(0), GA_SLOT(1), GA_SLOT(2), GA_SLOT(3), GA_SLOT(4))
{
    const uint i = get_global_id(0);
    GA_ADD(0);
    GA_ADD(1);
    GA_ADD(2);
    GA_ADD(3);
    GA_ADD(4);
}
