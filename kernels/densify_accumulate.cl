/* densify_accumulate.cl: the densification statistics of one photometric pass (the device
   trainer's `accumulate`, reings/backends/opencl/trainer.py).

   Must match reings.backends.reference_state.densify_accumulate with ndc_grad_norm (3DGS
   add_densification_stats; tests/test_adam_kernel.py): for rows with radius > 0,
   accum += |(v_u W/2, v_v H/2)|, count += 1, max_radii = max(max_radii, radius).

   Kernels
     densify_accumulate   one work-item per Gaussian: densify.h's densify_accumulate_one (which
                          project_bwd also runs, with stats = 1: the device trainer's
                          backward(stats=True); this kernel serves `accumulate`).

   Defines
     DENSIFY_FP64   1: the norm in double (as numpy); 0 (default): in float.
   Guards are written positively so that NaN fails them; built without fast-math.
*/
#pragma OPENCL FP_CONTRACT OFF

#define V_PROJ 10             /* record width of v_proj (project.cl, base.V_RECORD) */
#include "densify.h"

__kernel void densify_accumulate(const int n,
                                 __global const int *radii,      /* [N] from project_fwd */
                                 __global const float *v_proj,   /* [N, V_PROJ] (culled rows unread) */
                                 const dens_real half_w, const dens_real half_h,
                                 __global float *accum,          /* [N] += */
                                 __global int *count,            /* [N] += */
                                 __global float *max_radii)      /* [N] max= */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    densify_accumulate_one(i, radii, v_proj, half_w, half_h, accum, count, max_radii);
}
