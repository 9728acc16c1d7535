/* regularize.cl: DNGaussian's shape / scale / opacity penalties' gradients on the raw parameters,
   ADDED into the photometric pass's gradient buffers (the device trainer's `regularize`,
   reings/backends/opencl/trainer.py).

   Must match reings.backends.reference_loss.regularize_fwd_bwd (tests/test_adam_kernel.py): same
   formulas, same order of operations, in double where the device has cl_khr_fp64
   (REGULARIZE_FP64=1) as the numpy reference is, then rounded to float32 and added in float32.

   Kernels
     regularize_opacity_count  counts[0] += #(sigmoid(logit) > 0.2), counts[1] += #(< 0.2) (counts
                               zero on entry); each work-item a contiguous chunk, one atomic add
                               per item. With REGULARIZE_FP64, a compare of the float logit with
                               LOGIT_UNDER_SPLIT: the same counts without an exp per Gaussian.
     regularize_grads          the three penalties' gradients, one work-item per REG_VW Gaussians. The counts
                               are one of two pairs, used in turn: work-item 0 zeroes the other pair,
                               the next call's (the host fills both once, when they are made).
     regularize_value          the penalties' value, for the loop's logging iterations (the
                               device trainer's `regularize(..., value=True)` / `read_regularize`):
                               per chunk of `chunk` Gaussians, in order, the sums of max/min scale,
                               max scale^2, o^2 over o > 0.2, (1 - o)^2 over o < 0.2 and the two
                               counts, in `real`; the host adds the chunks in float64 and forms
                               reference_loss.regularize_fwd_bwd's value (tests/test_adam_kernel.py).
     opacity_decay             logits <- logit(f * sigmoid(logits)) in place (Binocular3DGS's opacity
                               decay, the device trainer's `decay_opacity`; twin
                               reference_view_warp.opacity_decay, float64): one work-item per Gaussian.

   Defines
     REGULARIZE_FP64   1: the per-Gaussian math in double (as numpy); 0 (default): in float.
     REG_VW            regularize_grads' Gaussians per work-item: 1 (default; GPUs) or 8 (CPUs: the same
                       operations on 8 lanes, the branches as selects; PoCL calls exp once per lane vector
                       instead of once per Gaussian; docs/perf_notes.md §31).
   Guards are written positively so that NaN fails them; built without fast-math.
*/
#pragma OPENCL FP_CONTRACT OFF

#ifndef REGULARIZE_FP64
#define REGULARIZE_FP64 0
#endif
#if REGULARIZE_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#else
typedef float real;
#endif

#define OPA_SPLIT ((real)0.2) /* reference_loss.OPACITY_SPLIT */
/* the largest float logit whose sigmoid (in double) is under OPA_SPLIT; the next float up, -0x1.62e42ep+0f, is over
   it (tests/test_adam_kernel.py::test_opacity_count_at_the_split checks both against numpy's float64 sigmoid) */
#define LOGIT_UNDER_SPLIT (-0x1.62e430p+0f)

__kernel void regularize_opacity_count(const int n, const int chunk,
                                       __global const float *logits,  /* [N] */
                                       __global int *count_pairs,     /* [2, 2] (> 0.2, < 0.2) pairs */
                                       const int pair)                /* the pair counted (zero on entry) */
{
    __global int *counts = count_pairs + 2 * pair;
    const int lo = get_global_id(0) * chunk;
    const int hi = min(n, lo + chunk);
    int nh = 0, nl = 0;
    for (int i = lo; i < hi; ++i) {
#if REGULARIZE_FP64
        /* o = 1 / (1 + exp(-x)) in double is above 0.2 exactly where the float x is above LOGIT_UNDER_SPLIT and
         * under 0.2 where x is at or below it (NaN: neither): no float lies within 3e-9 of -ln 4, where o = 0.2, so
         * o is at least 6e-10 from 0.2, beyond any double rounding (test_opacity_count_at_the_split). No exp per
         * Gaussian (PoCL: a scalar library call each) */
        const float x = logits[i];
        nh += x > LOGIT_UNDER_SPLIT;
        nl += x <= LOGIT_UNDER_SPLIT;
#else
        const real o = (real)1.0 / ((real)1.0 + exp(-(real)logits[i]));
        nh += o > OPA_SPLIT;
        nl += o < OPA_SPLIT;
#endif
    }
    if (nh) atomic_add(&counts[0], nh);
    if (nl) atomic_add(&counts[1], nl);
}

#ifndef REG_VW
#define REG_VW 1
#endif
/* regularize_grads' arguments (both widths) */
#define REG_GRADS_PARAMS                                                                       \
    const int n, __global const float *log_scales,  /* [N, 3] */                               \
        __global const float *logits,                /* [N] */                                  \
        __global int *count_pairs,                   /* [2, 2]: this call's pair, the other */  \
        const int pair,                              /* 0 / 1: the pair counted this call */    \
        const real shape_pena, const real scale_pena, const real opa_pena,                     \
        __global float *v_log_scales,                /* [N, 3] += */                            \
        __global float *v_logits                     /* [N] += */

#if REG_VW == 1
__kernel void regularize_grads(REG_GRADS_PARAMS)
{
    const int i = get_global_id(0);
    if (i == 0) { /* the other pair, zero for the next call's count: no fill command per step */
        count_pairs[2 * (1 - pair)] = 0;
        count_pairs[2 * (1 - pair) + 1] = 0;
    }
    if (!(i < n)) return;
    __global const int *counts = count_pairs + 2 * pair;
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
#elif REG_VW == 8
/* REG_VW 8 (CPU devices): a work-item per 8 Gaussians, the same operations on 8 lanes (rv), the argmax / argmin
   as masks (first occurrence on ties, as above) and the branches as selects: PoCL calls exp per work-item in
   the code above, once per 8 lanes here */
#if REGULARIZE_FP64
typedef double8 rv;
#else
typedef float8 rv;
#endif
#define RV_FROM(t) ((rv)((t)[0], (t)[1], (t)[2], (t)[3], (t)[4], (t)[5], (t)[6], (t)[7])) /* lanes from t[0..7] */
#define RSEL(a, b, c) ((c) ? (b) : (a)) /* select by a lane mask (common.h's SEL; PoCL calls OpenCL's select) */
__kernel void regularize_grads(REG_GRADS_PARAMS)
{
    const int g0 = get_global_id(0) * REG_VW;
    if (g0 == 0) { /* the other pair, zero for the next call's count: no fill command per step */
        count_pairs[2 * (1 - pair)] = 0;
        count_pairs[2 * (1 - pair) + 1] = 0;
    }
    if (!(g0 < n)) return;
    const int nl = min(REG_VW, n - g0); /* the real Gaussians of the lanes (the rest repeat the last) */
    __global const int *counts = count_pairs + 2 * pair;
    const real nn = (real)n;
    real t[4][REG_VW], out[4][REG_VW];
    for (int l = 0; l < REG_VW; ++l) {
        const int i = min(g0 + l, n - 1);
        for (int j = 0; j < 3; ++j) t[j][l] = log_scales[3 * i + j];
        t[3][l] = logits[i];
    }
    if (shape_pena != (real)0 || scale_pena != (real)0) {
        const rv l0 = RV_FROM(t[0]), l1 = RV_FROM(t[1]), l2 = RV_FROM(t[2]);
        /* imax / imin: the first occurrence on ties (numpy argmax / argmin); NaN compares false: index 0 */
        const rv zero = (rv)(0), one = (rv)(1), two = (rv)(2);
        rv lmax = l0, lmin = l0, imax = zero, imin = zero;
        imax = RSEL(imax, one, l1 > lmax);
        lmax = RSEL(lmax, l1, l1 > lmax);
        imin = RSEL(imin, one, l1 < lmin);
        lmin = RSEL(lmin, l1, l1 < lmin);
        imax = RSEL(imax, two, l2 > lmax);
        lmax = RSEL(lmax, l2, l2 > lmax);
        imin = RSEL(imin, two, l2 < lmin);
        lmin = RSEL(lmin, l2, l2 < lmin);
        rv g[3] = {zero, zero, zero};
        if (shape_pena != (real)0) {
            const rv ratio = exp(lmax - lmin);
            const rv up = ratio / nn, down = -ratio / nn;
            for (int j = 0; j < 3; ++j) {
                rv gs = zero;
                gs = RSEL(gs, gs + up, imax == (rv)(j));
                gs = RSEL(gs, gs + down, imin == (rv)(j));
                g[j] += shape_pena * gs;
            }
        }
        if (scale_pena != (real)0) {
            const rv s2 = (real)2.0 * exp((real)2.0 * lmax) / nn;
            for (int j = 0; j < 3; ++j) g[j] += scale_pena * RSEL(zero, s2, imax == (rv)(j));
        }
        for (int j = 0; j < 3; ++j) vstore8(g[j], 0, out[j]);
        for (int l = 0; l < nl; ++l)
            for (int j = 0; j < 3; ++j) {
                const size_t k = 3 * (size_t)(g0 + l) + j;
                v_log_scales[k] = v_log_scales[k] + (float)out[j][l];
            }
    }
    if (opa_pena != (real)0) {
        const rv o = (real)1.0 / ((real)1.0 + exp(-RV_FROM(t[3])));
        const int nh = counts[0], nlo = counts[1];
        rv go = (rv)(0);
        if (nh > 0) go = RSEL(go, (real)-2.0 * o / (real)nh, o > OPA_SPLIT);
        if (nlo > 0) go = RSEL(go, (real)-2.0 * ((real)1.0 - o) / (real)nlo, o < OPA_SPLIT);
        const rv d = opa_pena * ((go * o) * ((real)1.0 - o));
        vstore8(d, 0, out[3]);
        for (int l = 0; l < nl; ++l) v_logits[g0 + l] = v_logits[g0 + l] + (float)out[3][l];
    }
}
#else
#error "REG_VW must be 1 or 8"
#endif

#define REG_VALUE_COLS 6 /* regularize_value's sums per chunk (trainer.REG_VALUE_COLS) */

__kernel void regularize_value(const int n, const int chunk,
                               __global const float *log_scales,  /* [N, 3] */
                               __global const float *logits,      /* [N] */
                               __global real *partial)            /* [ceil(N / chunk), REG_VALUE_COLS] out */
{
    const int c = get_global_id(0);
    const int lo = c * chunk;
    if (!(lo < n)) return;
    const int hi = min(n, lo + chunk);
    real ratio = 0, s2 = 0, oh = 0, ol = 0, nh = 0, nl = 0;
    for (int i = lo; i < hi; ++i) {
        real l[3] = {log_scales[3 * i], log_scales[3 * i + 1], log_scales[3 * i + 2]};
        int imax = 0, imin = 0; /* first occurrence on ties (numpy argmax / argmin) */
        for (int j = 1; j < 3; ++j) {
            if (l[j] > l[imax]) imax = j;
            if (l[j] < l[imin]) imin = j;
        }
        ratio += exp(l[imax] - l[imin]);
        s2 += exp((real)2.0 * l[imax]);
        const real o = (real)1.0 / ((real)1.0 + exp(-(real)logits[i]));
        if (o > OPA_SPLIT) { oh += o * o; nh += (real)1; }
        if (o < OPA_SPLIT) { ol += ((real)1.0 - o) * ((real)1.0 - o); nl += (real)1; }
    }
    __global real *p = partial + (size_t)c * REG_VALUE_COLS;
    p[0] = ratio; p[1] = s2; p[2] = oh; p[3] = ol; p[4] = nh; p[5] = nl;
}

/* logit(f s(x)) = log f - log((1 - f) + exp(-x)), rewritten for x < 0 as
   x + log f - log1p((1 - f) exp(x)) so that exp never overflows: finite for every finite x.
   log_f = log f and one_minus_f = 1 - f come from the host (in `real`). Non-finite logits map as
   the twin maps them: NaN -> NaN, -inf -> -inf, +inf -> log f - log(1 - f). */
__kernel void opacity_decay(const int n, const real log_f, const real one_minus_f,
                            __global float *logits)  /* [N] in place */
{
    const int i = get_global_id(0);
    if (!(i < n)) return;
    const real x = (real)logits[i];
    real y;
    if (x >= (real)0)
        y = log_f - log(one_minus_f + exp(-x));
    else
        y = x + log_f - log1p(one_minus_f * exp(x));
    logits[i] = (float)y;
}

