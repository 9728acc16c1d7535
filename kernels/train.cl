/* train.cl: the small per-Gaussian kernels of the device-resident training engine
   (reings/backends/opencl/trainer.py); Adam is adam.cl.

   Kernels
     sh_pack            [N,1,3] sh_dc + the first k-1 rows of [N,kmax-1,3] sh_rest -> [N,k,3] (the
                        projection's SH input at the active degree); one work-item per output float.
     reg_opacity_count  counts[0] += #(sigmoid(logit) > 0.2), counts[1] += #(< 0.2) (counts zeroed
                        by the host); each work-item a contiguous chunk, one atomic add per item.
     reg_grads          DNGaussian's shape / scale / opacity penalties' gradients ADDED into the
                        gradient buffers (reings.losses.regularizers: same formulas, same order of
                        operations, in double where the device has cl_khr_fp64 (TRAIN_FP64=1) as
                        the numpy reference is, then rounded to float32 and added in float32).
     densify_accumulate 3DGS add_densification_stats for one view (reings.densify.accumulate with
                        ndc_grad_norm): for rows with radius > 0, accum += |(v_u W/2, v_v H/2)|,
                        count += 1, max_radii = max(max_radii, radius).

   Defines
     TRAIN_FP64   1: the per-Gaussian math of reg_grads / densify_accumulate in double (as numpy);
                  0 (default): in float.
   Guards are written positively so that NaN fails them; built without fast-math.
*/
#pragma OPENCL FP_CONTRACT OFF

#ifndef TRAIN_FP64
#define TRAIN_FP64 0
#endif
#if TRAIN_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#else
typedef float real;
#endif

#define OPA_SPLIT ((real)0.2) /* reings.losses.opacity_reg split */
#define V_PROJ 10             /* record width of v_proj (project.cl) */

__kernel void sh_pack(const int n, const int k, const int kmax,
                      __global const float *sh_dc,    /* [N, 1, 3] */
                      __global const float *sh_rest,  /* [N, kmax - 1, 3] */
                      __global float *sh)             /* [N, k, 3], 1 <= k <= kmax */
{
    const int i = get_global_id(0);
    const int row_len = 3 * k;
    if (!(i < n * row_len)) return;
    const int r = i / row_len, c = i - r * row_len;
    sh[i] = c < 3 ? sh_dc[3 * r + c] : sh_rest[r * 3 * (kmax - 1) + (c - 3)];
}

__kernel void reg_opacity_count(const int n, const int chunk,
                                __global const float *logits,  /* [N] */
                                __global int *counts)          /* [2] (> 0.2, < 0.2), zeroed */
{
    const int lo = get_global_id(0) * chunk;
    const int hi = min(n, lo + chunk);
    int nh = 0, nl = 0;
    for (int i = lo; i < hi; ++i) {
        const real o = (real)1.0 / ((real)1.0 + exp(-(real)logits[i]));
        nh += o > OPA_SPLIT;
        nl += o < OPA_SPLIT;
    }
    if (nh) atomic_add(&counts[0], nh);
    if (nl) atomic_add(&counts[1], nl);
}

__kernel void reg_grads(const int n,
                        __global const float *log_scales,   /* [N, 3] */
                        __global const float *logits,       /* [N] */
                        __global const int *counts,         /* [2] from reg_opacity_count */
                        const real shape_pena, const real scale_pena, const real opa_pena,
                        __global float *v_log_scales,       /* [N, 3] += */
                        __global float *v_logits)           /* [N] += */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    const real nn = (real)n;
    if (shape_pena != (real)0 || scale_pena != (real)0) {
        real l[3] = {log_scales[3 * i], log_scales[3 * i + 1], log_scales[3 * i + 2]};
        int imax = 0, imin = 0; /* first occurrence on ties (numpy argmax / argmin) */
        for (int j = 1; j < 3; ++j) {
            if (l[j] > l[imax]) imax = j;
            if (l[j] < l[imin]) imin = j;
        }
        real g[3] = {0, 0, 0};
        if (shape_pena != (real)0) {
            const real ratio = exp(l[imax] - l[imin]);
            real gs[3] = {0, 0, 0};
            gs[imax] += ratio / nn;
            gs[imin] += -ratio / nn;
            for (int j = 0; j < 3; ++j) g[j] += shape_pena * gs[j];
        }
        if (scale_pena != (real)0) {
            real gs[3] = {0, 0, 0};
            gs[imax] = (real)2.0 * exp((real)2.0 * l[imax]) / nn;
            for (int j = 0; j < 3; ++j) g[j] += scale_pena * gs[j];
        }
        for (int j = 0; j < 3; ++j) v_log_scales[3 * i + j] = v_log_scales[3 * i + j] + (float)g[j];
    }
    if (opa_pena != (real)0) {
        const real o = (real)1.0 / ((real)1.0 + exp(-(real)logits[i]));
        const int nh = counts[0], nl = counts[1];
        real go = 0;
        if (o > OPA_SPLIT && nh > 0) go = (real)-2.0 * o / (real)nh;
        if (o < OPA_SPLIT && nl > 0) go = (real)-2.0 * ((real)1.0 - o) / (real)nl;
        v_logits[i] = v_logits[i] + (float)(opa_pena * ((go * o) * ((real)1.0 - o)));
    }
}

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
