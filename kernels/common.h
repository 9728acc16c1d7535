/* common.h: constants and small helpers shared by every reings kernel file.
 *
 * The constants are the numbers of issue #2 §3 (and reings/backends/base.py, which must agree).
 * Capability defines arrive from reings.backends.opencl.quirks.build_defines:
 *   REINGS_CPU_SCHEDULE  1 on CPU devices (PoCL): no barriers / local memory in hot loops
 *   REINGS_NV_PTX        1 on NVIDIA: inline PTX (red.global.add.f32, shfl.sync) is allowed
 *   REINGS_FLOAT_ATOMICS 1 where cl_ext_float_atomics gives a native fp32 global add
 * Keep this header small and stable: every kernel file includes it.
 */
#ifndef REINGS_COMMON_H
#define REINGS_COMMON_H

#ifndef REINGS_CPU_SCHEDULE
#define REINGS_CPU_SCHEDULE 0
#endif
#ifndef REINGS_NV_PTX
#define REINGS_NV_PTX 0
#endif
#ifndef REINGS_FLOAT_ATOMICS
#define REINGS_FLOAT_ATOMICS 0
#endif

#ifndef TILE_SIZE
#define TILE_SIZE 16 /* tiles are TILE_SIZE x TILE_SIZE pixels */
#endif
#define TILE_PIXELS (TILE_SIZE * TILE_SIZE)
#define ALPHA_MIN (1.0f / 255.0f) /* a (pixel, Gaussian) pair with alpha below this is skipped (3DGS) */
#define ALPHA_MAX 0.99f           /* alpha clamp; no gradient flows through it */
#define T_MIN 1e-4f               /* a pixel stops *before* the Gaussian making T*(1-alpha) < T_MIN */
#define EPS2D 0.3f                /* low-pass dilation added to the 2D covariance diagonal */
#define CLAMP_GUARD 0.3f          /* Jacobian guard band, fraction of tan(fov/2) (gsplat) */
#define V_RECORD 10               /* floats per intersection gradient record (rasterize_bwd) */

/* The element count of a launch: the host's scalar `n` when count_at < 0, else counts[count_at],
 * a count that an earlier command of the queue wrote on the device (the sync-free binning,
 * docs/perf_notes.md §8: bin_count's V in ctrl[0], the scan's K in ctrl[1]); then `n` is only the
 * capacity the host sized the buffers and the launch for. */
inline uint launch_count(const uint n, __global const uint *counts, const int count_at) {
    return count_at < 0 ? n : counts[count_at];
}

/* The alpha box of a splat: the pixels outside it have alpha = o exp(power) < ALPHA_MIN, so they
 * are never blended. rasterize_prep skips the (pixel, Gaussian) pairs outside it; project_fwd cuts
 * the tile rect to the tiles it overlaps (a little wider: PROJ_BOX_SLACK in project.cl). With
 * lo = ALPHA_BOX_LO(o) = o / ALPHA_MIN >= 1 and a positive definite conic (A, B, C),
 * det = A C - B^2: power >= -ln(lo) needs dx^2 <= 2 ln(lo) C / det (q = C), and dy^2 likewise with
 * q = A; the half-width gets `rel` (ALPHA_BOX_REL: 1%) and ALPHA_BOX_PAD (0.5 px) of room for float
 * rounding. lo < 1: alpha < ALPHA_MIN everywhere. Arguments may be float or floatN. */
#define ALPHA_BOX_REL 1.01f
#define ALPHA_BOX_PAD 0.5f
#define ALPHA_BOX_LO(o) ((o) * 255.0f)
#define ALPHA_BOX_HALF(lo, q, det, rel) (sqrt(2.0f * log(lo) * (q) / (det)) * (rel) + ALPHA_BOX_PAD)

/* atomic_add_f32(p, v): *p += v, atomically, by the best means the device has.
 * NVIDIA: fire-and-forget PTX `red` (never a CAS loop there, docs/perf_notes.md §4.4). Native
 * cl_ext_float_atomics where the compiler exposes it. Otherwise a compare-and-swap loop (last
 * resort; CPU kernels avoid atomics altogether). */
#if REINGS_NV_PTX
inline void atomic_add_f32(volatile __global float *p, float v) {
    asm volatile("red.global.add.f32 [%0], %1;" ::"l"(p), "f"(v) : "memory");
}
#elif REINGS_FLOAT_ATOMICS && defined(__opencl_c_ext_fp32_global_atomic_add)
inline void atomic_add_f32(volatile __global float *p, float v) {
    atomic_fetch_add_explicit((volatile __global atomic_float *)p, v, memory_order_relaxed);
}
#else
inline void atomic_add_f32(volatile __global float *p, float v) {
    union { unsigned int u; float f; } old, nxt;
    old.f = *p;
    for (;;) {
        nxt.f = old.f + v;
        unsigned int seen = atomic_cmpxchg((volatile __global unsigned int *)p, old.u, nxt.u);
        if (seen == old.u) break;
        old.u = seen;
    }
}
#endif

/* PoCL 3.0 (pocl-binary-distribution) calls OpenCL's builtins rather than inlining them, spilling every live
 * vector register around each call (docs/perf_notes.md §17). Plain-operator forms with the same value:
 * SEL(a, b, c) is select(a, b, c) (a vector condition selects by its sign bit, as select; a scalar one by
 * != 0), any8(m) is any(m) of an int8. */
#define SEL(a, b, c) ((c) ? (b) : (a))
inline int any8(int8 m) {
    int4 a = m.lo | m.hi;
    int2 b = a.lo | a.hi;
    return (b.x | b.y) < 0;
}

#endif /* REINGS_COMMON_H */
