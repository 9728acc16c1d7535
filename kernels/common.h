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
#ifndef T_MIN
#define T_MIN 1e-4f /* a pixel stops *before* the Gaussian making T*(1-alpha) < T_MIN */
#endif
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
/* The half-width from ln(lo), computed once per splat for both axes and the cut (PoCL calls its log, Sleef's,
 * and on a vector once per lane; docs/perf_notes.md §30). */
/* BOX_SQRT: the sqrt it takes where it is expanded (project.cl's lanes: VSQRT, the same values) */
#define BOX_SQRT(x) sqrt(x)
#define ALPHA_BOX_HALF_LN(ln_lo, q, det, rel) (BOX_SQRT(2.0f * (ln_lo) * (q) / (det)) * (rel) + ALPHA_BOX_PAD)
/* The power below which alpha = o exp(power) < ALPHA_MIN for certain: -ln(lo) less ALPHA_CUT_PAD (a
 * factor e^-0.001 in alpha, far above float32's rounding of log, exp and the product). The CPU
 * rasterizer skips a pixel vector's exp where every lane's power is below it: those lanes fail the
 * alpha >= ALPHA_MIN test anyway, so the outputs keep their bits (record field 14). */
#define ALPHA_CUT_PAD 1e-3f
#define ALPHA_CUT_LN(ln_lo) (-(ln_lo) - ALPHA_CUT_PAD) /* ln_lo = ln(lo) */

/* The rasterizer's record of Gaussian g, from the projection's stored floats: (u, v, A, B, C, o, r, g,
 * b, z), the pixel box outside of which alpha < ALPHA_MIN ([xlo, xhi] x [ylo, yhi], empty where
 * o < 1/255 or not finite; no box, 1e7 wide, where the conic is not positive definite) and the power
 * cut ALPHA_CUT_LN (0 with an empty box), 16 floats (the last 0).
 * rasterize.cl's rasterize_prep (an uploaded projection) and project.cl's project_fwd (a forward on
 * the device, which writes the record itself: one launch fewer) both call this; project.cl's
 * raster_prep_lanes (PROJ_BLOCK_IO) is the same operations on 16 lanes: change both together
 * (tests/test_project.py::test_project_block_io_keeps_the_bits compares them byte for byte). */
static inline void raster_prep_one(const int g, __global const float *means2d, __global const float *conics,
                                   __global const float *colors, __global const float *opacities,
                                   __global const float *depths, __global float *packed) {
    const float u = means2d[2 * g], v = means2d[2 * g + 1];
    const float A = conics[3 * g], B = conics[3 * g + 1], C = conics[3 * g + 2];
    const float o = opacities[g];
    float xlo = 1.0f, xhi = 0.0f, ylo = 1.0f, yhi = 0.0f; /* empty box */
    float cut = 0.0f;                                    /* the power cut: none (an empty box) */
    const float lo = ALPHA_BOX_LO(o);
    /* o < 1/255 (or NaN): alpha < ALPHA_MIN everywhere -> never blended */
    if (lo >= 1.0f && isfinite(u) && isfinite(v) && isfinite(lo)) {
        const float det = A * C - B * B;
        const float ln_lo = log(lo);
        /* the alpha box: project_fwd cuts the tile rect to it (a little wider) */
        float ex = 1e7f, ey = 1e7f; /* not positive definite: no box, the pixel test decides */
        if (det > 0.0f && A > 0.0f && C > 0.0f && isfinite(det)) {
            ex = fmin(ALPHA_BOX_HALF_LN(ln_lo, C, det, ALPHA_BOX_REL), 1e7f);
            ey = fmin(ALPHA_BOX_HALF_LN(ln_lo, A, det, ALPHA_BOX_REL), 1e7f);
        }
        /* pixel i (centre i + 0.5) is inside when |u - (i + 0.5)| <= ex */
        xlo = clamp(ceil(u - ex - 0.5f), -2.0f, 1e7f);
        xhi = clamp(floor(u + ex - 0.5f), -2.0f, 1e7f);
        ylo = clamp(ceil(v - ey - 0.5f), -2.0f, 1e7f);
        yhi = clamp(floor(v + ey - 0.5f), -2.0f, 1e7f);
        cut = ALPHA_CUT_LN(ln_lo);
    }
    __global float *rec = packed + (size_t)g * 16;
    rec[0] = u;
    rec[1] = v;
    rec[2] = A;
    rec[3] = B;
    rec[4] = C;
    rec[5] = o;
    rec[6] = colors[3 * g];
    rec[7] = colors[3 * g + 1];
    rec[8] = colors[3 * g + 2];
    rec[9] = depths[g];
    rec[10] = xlo;
    rec[11] = xhi;
    rec[12] = ylo;
    rec[13] = yhi;
    rec[14] = cut;
    rec[15] = 0.0f;
}

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
 * != 0), any8(m) / any16(m) are any(m) of an int8 / int16.
 * With REINGS_CLANG_BUILTINS (quirks.build_defines: 1 on PoCL's CPU devices) any8 / any16 take clang's
 * __builtin_reduce_or where the compiler has it: LLVM lowers the OR reduce of a compare's mask to one mask
 * test (AVX-512: kortestw) where the tree of halves below was a chain of extracts and shuffles
 * (docs/perf_notes.md §30). The same value either way. Not for Oclgrind: its interpreter has no
 * vector-reduce intrinsic. */
#define SEL(a, b, c) ((c) ? (b) : (a))
#ifndef REINGS_CLANG_BUILTINS
#define REINGS_CLANG_BUILTINS 0
#endif
/* which of the builtins this compiler has (both 0 without REINGS_CLANG_BUILTINS): REINGS_ANY_REDUCE for any8 / any16
 * below, REINGS_HAS_PREFETCH for rasterize.cl's RASTER_PREFETCH */
#define REINGS_ANY_REDUCE 0
#define REINGS_HAS_PREFETCH 0
#define REINGS_HAS_CTZ 0
#if REINGS_CLANG_BUILTINS && defined(__has_builtin)
#if __has_builtin(__builtin_reduce_or)
#undef REINGS_ANY_REDUCE
#define REINGS_ANY_REDUCE 1
#endif
#if __has_builtin(__builtin_prefetch)
#undef REINGS_HAS_PREFETCH
#define REINGS_HAS_PREFETCH 1
#endif
#if __has_builtin(__builtin_ctz)
#undef REINGS_HAS_CTZ
#define REINGS_HAS_CTZ 1
#endif
#endif
/* low_bit(m): the index of m's lowest set bit (m != 0); with REINGS_HAS_CTZ one tzcnt, else OpenCL's clz of
 * the bit alone (a call on PoCL) */
#if REINGS_HAS_CTZ
inline int low_bit(uint m) { return __builtin_ctz(m); }
#else
inline int low_bit(uint m) { return 31 - (int)clz(m & (0u - m)); }
#endif
#if REINGS_ANY_REDUCE
inline int any8(int8 m) { return __builtin_reduce_or(m) < 0; }
inline int any16(int16 m) { return __builtin_reduce_or(m) < 0; }
#else
inline int any8(int8 m) {
    int4 a = m.lo | m.hi;
    int2 b = a.lo | a.hi;
    return (b.x | b.y) < 0;
}
inline int any16(int16 m) { return any8(m.lo | m.hi); }
#endif

/* Scalar math without PoCL's calls (REINGS_SCALAR_BUILTINS, default REINGS_CLANG_BUILTINS): clang's
 * __builtin_sqrtf / fabsf / floorf / isfinite lower to LLVM's intrinsics (one instruction each: sqrtss,
 * andps, roundss, a compare; IEEE sqrt correctly rounded), which the work-item loop vectorizer can widen,
 * where PoCL's library calls stop it and spill around each call (docs/perf_notes.md §17, §35). The same values as OpenCL's builtins
 * (the byte tests compare both builds). Elsewhere (GPUs, Oclgrind) the OpenCL builtins. */
#ifndef REINGS_SCALAR_BUILTINS
#define REINGS_SCALAR_BUILTINS REINGS_CLANG_BUILTINS
#endif
#if REINGS_SCALAR_BUILTINS
#define SQRT1(x) __builtin_sqrtf(x)
#define FABS1(x) __builtin_fabsf(x)
#define FLOOR1(x) __builtin_floorf(x)
#define ISFINITE1(x) __builtin_isfinite(x)
#else
#define SQRT1(x) sqrt(x)
#define FABS1(x) fabs(x)
#define FLOOR1(x) floor(x)
#define ISFINITE1(x) isfinite(x)
#endif

/* FABSG(x): fabs of any floating type (float, double, their vectors): clang's __builtin_elementwise_abs where
 * REINGS_SCALAR_BUILTINS holds and the compiler has it (llvm.fabs: a mask of the sign bit), else fabs.
 * SIGNF(x): OpenCL's sign of a float, with REINGS_SCALAR_BUILTINS in plain operators: 1, -1, x itself for +-0
 * (sign(+-0) = +-0), 0 for NaN. */
#if REINGS_SCALAR_BUILTINS && defined(__has_builtin)
#if __has_builtin(__builtin_elementwise_abs)
#define FABSG(x) __builtin_elementwise_abs(x)
#endif
#endif
#ifndef FABSG
#define FABSG(x) fabs(x)
#endif
#if REINGS_SCALAR_BUILTINS
#define SIGNF(x) ((x) > 0.0f ? 1.0f : ((x) < 0.0f ? -1.0f : ((x) == 0.0f ? (x) : 0.0f)))
#else
#define SIGNF(x) sign(x)
#endif

#endif /* REINGS_COMMON_H */
