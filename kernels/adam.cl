/* adam.cl: one Adam step of one parameter group, in place, all state on the device.

   Computes the same float32 operation sequence as `reings.backends.reference_state.adam_update` (numpy,
   torch.optim.Adam's formula with t = the group's own step count):

       m = b1*m + (1-b1)*g
       v = b2*v + (1-b2)*(g*g)
       p = p + (m / (sqrt(v) * inv_sqrt_bc2 + eps)) * neg_step        neg_step = -lr / (1 - b1^t)
                                                                       inv_sqrt_bc2 = 1 / sqrt(1 - b2^t)
   every operation rounded to float32 in that order (FP_CONTRACT OFF: no fused multiply-adds),
   except sqrt(v) * inv_sqrt_bc2, which numpy evaluates in float64 (a float64 scalar operand) and
   this kernel too where the device has cl_khr_fp64 (ADAM_FP64=1). The host computes the scalars
   (lr schedule, bias corrections) per step and passes them as arguments.

   Kernels
     adam_step   one work-item per element of the group's [rows, cols] parameter (p, m, v share
                 that layout), 2-D range (cols, rows). The gradient is read from a strided view of a [rows, g_stride]
                 buffer: column c of row r is g[r * g_stride + g_off + c] for c < g_cols and 0
                 beyond. That is how the SH groups read the projection backward's v_sh [N, k, 3]
                 (k = active SH coefficients): sh_dc takes columns 0..2, sh_rest columns 3..3k-1
                 of it and zeros for its inactive coefficients (whose moments then stay zero and
                 whose values stay put, as with numpy Adam on a zero gradient).
     adam_step_flat  the same for a gradient laid out like the parameter (1-D, one per element).

   Defines
     ADAM_FP64   1: inv_sqrt_bc2 is a double and that one product is done in double (bit-identical
                 to numpy where sqrt and division are correctly rounded, e.g. PoCL); 0 (default):
                 float (float32 rounding of that product).
   Not handled: weight decay, amsgrad (3DGS uses neither).
*/
#pragma OPENCL FP_CONTRACT OFF

#ifndef ADAM_FP64
#define ADAM_FP64 0
#endif
#if ADAM_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double bc_t;
#else
typedef float bc_t;
#endif

__kernel void adam_step(const uint rows, const uint cols,
                        __global float *p,          /* [rows, cols] parameter */
                        __global float *m,          /* [rows, cols] first moment */
                        __global float *v,          /* [rows, cols] second moment */
                        __global const float *g,    /* [rows, g_stride] gradient (strided view) */
                        const uint g_stride, const uint g_off, const uint g_cols,
                        const float b1, const float omb1,   /* beta1, float32(1 - beta1) */
                        const float b2, const float omb2,   /* beta2, float32(1 - beta2) */
                        const bc_t inv_sqrt_bc2,            /* 1 / sqrt(1 - beta2^t) */
                        const float eps,
                        const float neg_step)               /* -lr / (1 - beta1^t) */
{
    /* 2-D range (columns, rows): no index division */
    const uint c = get_global_id(0), r = get_global_id(1);
    if (!(c < cols && r < rows)) return;
    const uint i = r * cols + c;
    const float gi = c < g_cols ? g[r * g_stride + g_off + c] : 0.0f;
    const float mi = m[i] * b1 + gi * omb1;
    const float vi = v[i] * b2 + (gi * gi) * omb2;
    m[i] = mi;
    v[i] = vi;
    const float den = (float)((bc_t)sqrt(vi) * inv_sqrt_bc2) + eps;
    p[i] = p[i] + (mi / den) * neg_step;
}

/* adam_step for a gradient laid out like the parameter (g_stride == cols, g_off == 0,
   g_cols == cols): no index arithmetic, the form CPU compilers vectorize. */
__kernel void adam_step_flat(const uint total,
                             __global float *p, __global float *m, __global float *v, /* [total] */
                             __global const float *g,                                 /* [total] */
                             const float b1, const float omb1, const float b2, const float omb2,
                             const bc_t inv_sqrt_bc2, const float eps, const float neg_step)
{
    const uint i = get_global_id(0);
    if (!(i < total)) return;
    const float gi = g[i];
    const float mi = m[i] * b1 + gi * omb1;
    const float vi = v[i] * b2 + (gi * gi) * omb2;
    m[i] = mi;
    v[i] = vi;
    const float den = (float)((bc_t)sqrt(vi) * inv_sqrt_bc2) + eps;
    p[i] = p[i] + (mi / den) * neg_step;
}
