/* densify_accumulate.cl: the densification statistics of one photometric pass (the device
   trainer's `accumulate`, reings/backends/opencl/trainer.py).

   Must match reings.backends.reference_state.densify_accumulate with ndc_grad_norm (3DGS
   add_densification_stats; tests/test_adam_kernel.py): for rows with radius > 0,
   accum += |(v_u W/2, v_v H/2)|, count += 1, max_radii = max(max_radii, radius).

   Kernels
     densify_accumulate   one work-item per Gaussian.

   Defines
     DENSIFY_FP64   1: the norm in double (as numpy); 0 (default): in float.
   Guards are written positively so that NaN fails them; built without fast-math.
*/
#pragma OPENCL FP_CONTRACT OFF

#ifndef DENSIFY_FP64
#define DENSIFY_FP64 0
#endif
#if DENSIFY_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#else
typedef float real;
#endif

#define V_PROJ 10             /* record width of v_proj (project.cl, base.V_RECORD) */

__kernel void densify_accumulate(const int n,
                                 __global const int *radii,      /* [N] from project_fwd */
                                 __global const float *v_proj,   /* [N, V_PROJ] (culled rows unread) */
                                 const real half_w, const real half_h,
                                 __global float *accum,          /* [N] += */
                                 __global int *count,            /* [N] += */
                                 __global float *max_radii)      /* [N] max= */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    const int r = radii[i];
    if (!(r > 0)) return;
    const real x = (real)v_proj[(size_t)i * V_PROJ] * half_w;
    const real y = (real)v_proj[(size_t)i * V_PROJ + 1] * half_h;
    accum[i] = accum[i] + (float)hypot(x, y);
    count[i] = count[i] + 1;
    max_radii[i] = fmax(max_radii[i], (float)r);
}
