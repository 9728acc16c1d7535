/* adam.cl: Adam steps of parameter groups (one, or up to six in one launch), in place, all state on the device.

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
     adam_step_multi  up to ADAM_SLOTS (6) groups in one launch (the device trainer's `adam_step`:
                 one launch per call instead of one per group; a launch costs ~10 us of queue
                 latency on an H100). 2-D range (LX * work-groups, LY), local size (LX, LY): each
                 slot owns a run of work-groups (wg_end: the cumulative work-group count at its
                 end), so the slot is uniform over a work-group (read from get_group_id(0)); a
                 work-group holds LY "lines" of LX lanes. A flat slot (rpl == 0: gradient laid out
                 like the parameter) maps line L, lane x to element L * LX + x < rows (rows = its
                 element count); with sh 1 the same flat mapping reads a strided gradient view
                 (row = element / cols: one division per element, every lane busy and p, m, v read
                 contiguously; the GPUs' mapping of the SH groups since session 25). A strided slot
                 (as adam_step: gradient column c of row r at g[r * g_stride + g_off + c], zero for
                 c >= g_cols) puts rpl rows of 1 << sh lanes
                 in a line: lane x is row L * rpl + (x >> sh), column x & ((1 << sh) - 1), used
                 where that column is < cols (the host makes LX at least every strided slot's
                 cols, so no index division is needed; a row wider than half a line takes the
                 whole line, rpl = 1). Unused slots have no work-groups (their wg_end is the
                 previous one) and are never read; they may repeat another slot's buffers. The
                 slots' buffers must not overlap, except the gradients (read only): the two SH
                 groups read one buffer through different views. b1, 1-b1, b2, 1-b2 and eps are
                 the optimizer's (shared), inv_sqrt_bc2 and neg_step per slot (lr and step count
                 are per group).
   All three kernels do the per-element update through `adam_elem`, one float32 operation
   sequence: the same bits whichever kernel steps a group.

   Defines
     ADAM_FP64   1: inv_sqrt_bc2 is a double and that one product is done in double (bit-identical
                 to numpy where sqrt and division are correctly rounded, e.g. PoCL); 0 (default):
                 float (float32 rounding of that product).
     ADAM_MULTI_SPLIT  1: adam_step_multi starts each slot's work with a work-group barrier (the
                 device trainer sets it on CPU devices: PoCL compiles each slot into a work-item
                 loop of its own instead of selecting the slot per work-item); 0 (default): none.
                 The same bits either way.
     ADAM_LOADS_FIRST  1: an element's p is read with its m and v, before the stores to m and v (the
                 device trainer sets it on GPUs); 0 (default): after them. The compiler cannot move the
                 load above the stores itself (p, m and v might alias, as far as it knows; `restrict`
                 did not move it on NVIDIA), and after them it costs a second memory round trip per
                 element: NVIDIA H200, scene C at SH 3, Adam's device time 0.176 -> 0.156 ms (docs/perf_notes.md
                 §39). CPUs keep 0, whose text is the loads where their values are used: PoCL 3.0 (LLVM
                 14, 2 Xeon cores) ran adam_step_multi into a segmentation fault with any other order
                 of the loads (1, or only m's and v's loads moved up; tests/test_adam_multi.py), and a
                 CPU's caches hide the round trip. The same bits either way (the same values,
                 operations and order; checked under Oclgrind and in the GPUs' test runs).
   Not handled: weight decay, amsgrad (3DGS uses neither).
*/
#pragma OPENCL FP_CONTRACT OFF

#include "common.h"

#ifndef ADAM_FP64
#define ADAM_FP64 0
#endif
#ifndef ADAM_MULTI_SPLIT
#define ADAM_MULTI_SPLIT 0
#endif
#ifndef ADAM_LOADS_FIRST
#define ADAM_LOADS_FIRST 0
#endif
#if ADAM_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double bc_t;
#else
typedef float bc_t;
#endif

/* One element: m, v and p updated in place (the operation order of the file's comment). */
static inline void adam_elem(__global float *p, __global float *m, __global float *v, const uint i, const float gi,
                             const float b1, const float omb1, const float b2, const float omb2,
                             const bc_t inv_sqrt_bc2, const float eps, const float neg_step)
{
#if ADAM_LOADS_FIRST
    const float p0 = p[i], m0 = m[i], v0 = v[i]; /* the three loads before the stores (the header's define) */
#else /* each load where its value is used (the form PoCL runs: the header's ADAM_LOADS_FIRST) */
#define p0 p[i]
#define m0 m[i]
#define v0 v[i]
#endif
    const float mi = m0 * b1 + gi * omb1;
    const float vi = v0 * b2 + (gi * gi) * omb2;
    m[i] = mi;
    v[i] = vi;
    const float den = (float)((bc_t)SQRT1(vi) * inv_sqrt_bc2) + eps;
    p[i] = p0 + (mi / den) * neg_step;
#undef p0
#undef m0
#undef v0
}

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
    adam_elem(p, m, v, i, gi, b1, omb1, b2, omb2, inv_sqrt_bc2, eps, neg_step);
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
    adam_elem(p, m, v, i, gi, b1, omb1, b2, omb2, inv_sqrt_bc2, eps, neg_step);
}

/* adam_step_multi: up to ADAM_SLOTS groups in one launch (the header's description). */
#define ADAM_SLOTS 6
#define ADAM_SLOT_ARGS(s)                                                                              \
    __global float *p##s, __global float *m##s, __global float *v##s, /* the group's [rows, cols] */   \
    __global const float *g##s,                     /* its gradient (flat, or a strided view) */        \
    const uint wg_end##s,                           /* cumulative work-groups at the slot's end */      \
    const uint rows##s,                             /* rows (flat: elements) */                         \
    const uint cols##s,                             /* columns (flat: unused) */                        \
    const uint rpl##s,                              /* rows per line; 0: flat */                        \
    const uint sh##s,                               /* lanes per row: 1 << sh */                        \
    const uint g_stride##s, const uint g_off##s, const uint g_cols##s, /* strided view (flat: unused) */ \
    const bc_t inv_sqrt_bc2##s, const float neg_step##s

/* One work-group of one slot: wgi is its index among the slot's work-groups. */
static inline void adam_multi_slot(const uint wgi, __global float *p, __global float *m, __global float *v,
                                   __global const float *g, const uint rows, const uint cols, const uint rpl,
                                   const uint sh, const uint g_stride, const uint g_off, const uint g_cols,
                                   const float b1, const float omb1, const float b2, const float omb2,
                                   const bc_t inv_sqrt_bc2, const float eps, const float neg_step)
{
#if ADAM_MULTI_SPLIT
    /* reached by the whole work-group (the slot is uniform over it): PoCL then makes this slot's
       work-item loop a region of its own, without the slot selection in it */
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
    const uint x = get_local_id(0);
    const uint line = wgi * get_local_size(1) + get_local_id(1);  /* the slot's line */
    if (rpl == 0) {  /* flat: consecutive elements along the lanes */
        const uint i = line * get_local_size(0) + x;
        if (i < rows) {
            float gi;
            if (sh == 0) {
                gi = g[i];
            } else { /* sh 1: a strided gradient view stepped flat (element i is row i / cols, column i % cols) */
                const uint r = i / cols, c = i - r * cols;
                gi = c < g_cols ? g[r * g_stride + g_off + c] : 0.0f;
            }
            adam_elem(p, m, v, i, gi, b1, omb1, b2, omb2, inv_sqrt_bc2, eps, neg_step);
        }
        return;
    }
    /* strided: rpl rows of 1 << sh lanes per line (no division) */
    const uint sub = x >> sh, c = x & ((1u << sh) - 1u), r = line * rpl + sub;
    if (!(sub < rpl && c < cols && r < rows)) return;
    const float gi = c < g_cols ? g[r * g_stride + g_off + c] : 0.0f;
    adam_elem(p, m, v, r * cols + c, gi, b1, omb1, b2, omb2, inv_sqrt_bc2, eps, neg_step);
}

#define ADAM_SLOT(s, start)                                                                            \
    adam_multi_slot(wg - (start), p##s, m##s, v##s, g##s, rows##s, cols##s, rpl##s, sh##s, g_stride##s,  \
                    g_off##s, g_cols##s, b1, omb1, b2, omb2, inv_sqrt_bc2##s, eps, neg_step##s)

__kernel void adam_step_multi(const float b1, const float omb1, const float b2, const float omb2, const float eps,
                              ADAM_SLOT_ARGS(0), ADAM_SLOT_ARGS(1), ADAM_SLOT_ARGS(2),
                              ADAM_SLOT_ARGS(3), ADAM_SLOT_ARGS(4), ADAM_SLOT_ARGS(5))
{
    /* the slot of this work-group: uniform over it (work-groups along dimension 0, which takes the
       largest counts everywhere) */
    const uint wg = get_group_id(0);
    if (wg < wg_end0) ADAM_SLOT(0, 0u);
    else if (wg < wg_end1) ADAM_SLOT(1, wg_end0);
    else if (wg < wg_end2) ADAM_SLOT(2, wg_end1);
    else if (wg < wg_end3) ADAM_SLOT(3, wg_end2);
    else if (wg < wg_end4) ADAM_SLOT(4, wg_end3);
    else if (wg < wg_end5) ADAM_SLOT(5, wg_end4);
}
