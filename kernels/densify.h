/* densify.h: the densification statistics of one Gaussian after a photometric backward (3DGS
   add_densification_stats with ndc_grad_norm): for a row with radius > 0,
   accum += |(v_u W/2, v_v H/2)|, count += 1, max_radii = max(max_radii, radius); the norm as
   sqrt(x^2 + y^2) with DENSIFY_FP64 (in double, each operation IEEE-rounded and none fused: numpy's float64
   gives the same bits), hypot in float without it.

   Must match reings.backends.reference_state.densify_accumulate with ndc_grad_norm
   (tests/test_adam_kernel.py). One function, two callers with the same bits: densify_accumulate.cl
   (the device trainer's `accumulate`, a launch of its own) and project.cl's project_bwd with
   stats = 1 (the device trainer's `backward(stats=True)`: the photometric pass's statistics taken
   where its v_proj rows are read anyway, one launch fewer per step; docs/perf_notes.md §25).
   Contraction is off inside the function whatever the includer's setting (project.cl's is the
   default), as in densify_accumulate.cl: x * x + y * y is two rounded products and a rounded sum.

   Defines
     DENSIFY_FP64   1: the norm in double (as numpy); 0 (default): in float.
     V_PROJ         the v_proj record's width (10, base.V_RECORD), unless the includer set it. */
#ifndef REINGS_DENSIFY_H
#define REINGS_DENSIFY_H

#ifndef DENSIFY_FP64
#define DENSIFY_FP64 0
#endif
#if DENSIFY_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double dens_real;
#else
typedef float dens_real;
#endif
#ifndef V_PROJ
#define V_PROJ 10
#endif

/* Row i's statistics from its record v_proj[i] (the 2D mean gradient is its first two floats);
   rows with radius <= 0 (culled, dropped; NaN fails the guard) are left alone. */
static inline void densify_accumulate_one(const int i, __global const int *radii, __global const float *v_proj,
                                          const dens_real half_w, const dens_real half_h, __global float *accum,
                                          __global int *count, __global float *max_radii) {
#pragma OPENCL FP_CONTRACT OFF /* in this block only (C99 7.12.2): as densify_accumulate.cl builds it */
    const int r = radii[i];
    if (!(r > 0)) return;
    const dens_real x = (dens_real)v_proj[(size_t)i * V_PROJ] * half_w;
    const dens_real y = (dens_real)v_proj[(size_t)i * V_PROJ + 1] * half_h;
#if DENSIFY_FP64
    /* the norm as sqrt(x x + y y), not hypot (a call to Sleef's hypot per Gaussian on PoCL, ~17 % of project_bwd's
       samples): in double the squares of float inputs scaled by W/2, H/2 neither overflow nor underflow, and each
       operation is IEEE-rounded (contraction is off here), so reference_state.ndc_grad_norm's numpy gives the
       same bits */
    accum[i] = accum[i] + (float)sqrt(x * x + y * y);
#else
    accum[i] = accum[i] + hypot(x, y); /* in float the squares could overflow */
#endif
    count[i] = count[i] + 1;
    max_radii[i] = fmax(max_radii[i], (float)r);
}

#endif
