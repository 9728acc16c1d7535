/* project.cl: per-Gaussian projection (EWA splatting + SH colour) and its backward.

   Computes the same function as `reings.backends.reference.project_fwd` / `project_bwd`
   (float64 numpy); the conventions are those of reings/backends/base.py and the issue spec §3:

     q <- q / |q| (w, x, y, z);  R(q) standard;  Sigma = R S S^T R^T, S = diag(exp(log_scales))
     t = Rc mu + tc;  cull unless t_z > near
     u = fx t_x / t_z + cx,  v = fy t_y / t_z + cy
     J at the gsplat-clamped (t_x/t_z, t_y/t_z);  Sigma2d = J Rc Sigma Rc^T J^T + EPS2D I
     cull unless det > 0;  conic = Sigma2d^-1 = (A, B, C)
     r = ceil(3 sqrt(lambda_max)),  lambda_max = mid + sqrt(max(0.1, mid^2 - det))
     tiles [floor((u - r)/16), ceil((u + r)/16)) (y likewise), clamped to the grid; cull if empty
     colour = max(0, SH(normalize(mu - campos)) + 0.5);  opacity = sigmoid(logit) or the override
     DropGaussian (drop_threshold > 0; docs/method.md §9): cull unless DROP_HASH(gid, drop_key) >=
     drop_threshold; a kept Gaussian's opacity is sigmoid(logit) * drop_scale (1 / (1 - rate))
     tile rect (opacity-aware, `alpha_rect`): the tiles above, cut to the tiles that the alpha box
     of the opacity o (common.h, rasterize_prep's box with PROJ_BOX_SLACK more room) overlaps;
     o < 1/255: empty rect (all zeros), the Gaussian stays visible (radii unchanged)

   Kernels
     project_fwd   one work-item per Gaussian (gid); writes every output row (culled rows: zeros),
                   the depth sort key and gid, and zeroes the binning's visible count (ctrl[2],
                   kernels/bin.cl). The key is the float bits of t_z wherever t_z > near (finite),
                   DEPTH_KEY_CULLED elsewhere: the near-plane test only, so it is a function of the
                   means and the camera's z row (and near) alone. Also the rasterizer's record of
                   each Gaussian (`raster_prep_one`, common.h: rasterize_prep's code on the floats
                   just stored), so a forward on the device launches no rasterize_prep.
     project_bwd   one work-item per Gaussian; chains the per-Gaussian cotangents
                   (v_means2d, v_conics, v_colors, v_opacities, v_depths, packed as a [N, 10] record)
                   back to the raw fields (true derivative of project_fwd, clamps included). With
                   grad_acc 1 it adds the gradients of the fields in grad_mask into its outputs and
                   leaves the other fields alone (GRAD_F: a second backward into held gradients,
                   the device trainer's `backward(into=)`, with no separate add). With stats 1
                   it also adds each Gaussian's densification statistics (densify.h, the same
                   bits as densify_accumulate.cl: the photometric backward's, one launch fewer).
     project_bwd_opacity  project_bwd with grad_mask 8 alone (an opacity-only backward: the soft depth
                   term's, the DTU background pass's), the same bytes in every output: radii > 0 for the
                   culling, no projection, the opacity's chain alone (~1/10 of project_bwd's time on PoCL).

   Defines
     SH_K          number of SH coefficients per channel (1, 4, 9 or 16); default 1.
     DENSIFY_FP64  project_bwd's statistics in double (densify.h; the host sets it where the device
                   has cl_khr_fp64, as for densify_accumulate.cl).
     PROJ_VW       Gaussians per work-item, 1, 8 or 16 (default 1). 8 or 16 on CPU devices (16 on PoCL's
                   CPUs, where 16 lanes take PROJ_BLOCK_IO, and where the native float vector is 16
                   wide; else 8: backend.proj_lanes): the math
                   runs on float8 / float16 lanes (through PoCL's vector builtins, ~8x the scalar code,
                   which PoCL 3.0 does not vectorize across work-items); 1 on GPUs. The code is
                   written once over the lane types vf / vi; culling is a lane mask, never a branch.
     PROJ_BLOCK_IO 1: a 16-lane work-item's rows loaded and stored as blocks and its records written
                   on the lanes (below, "PROJ_BLOCK_IO"); default 1 where PROJ_VW is 16 and clang's
                   __builtin_shufflevector exists (PoCL's CPU builds), else 0. The same bytes.

   Culling (radii 0, zero row; matches the reference): dropped by the DropGaussian mask (then no
   tile intersections, zero gradients, no densification statistics, as any culled Gaussian); any
   non-finite raw field; |q| < 1e-12;
   t_z <= near (or not finite); det(Sigma2d) <= 0; a projected value (t, u, v, Sigma2d, conic,
   lambda_max, colour) not finite in float32; an empty 3-sigma tile rect (the opacity-aware cut
   never culls: `alpha_rect`). det, conic and lambda_max are
   computed on Sigma2d / max(a, c) so that a huge but representable Sigma2d does not overflow.
   The backward scales huge cotangents by a power of two (it is linear in them) so that overflow
   gives +-inf, never NaN.

   Not handled here: binning (bin.cl), blending (rasterize.cl). Guards are written positively so
   that NaN fails them; the file must be built without fast-math options.
*/
#include "common.h"

#ifndef SH_K
#define SH_K 1
#endif

#define PROJ_EPS2D EPS2D           /* low-pass dilation on the 2D covariance diagonal (common.h) */
#define PROJ_LAMBDA_FLOOR 0.1f     /* floor of the eigenvalue spread term (3DGS radius rule) */
#define PROJ_SIGMAS 3.0f           /* radius = ceil(3 sqrt(lambda_max)) */
#define PROJ_BOX_SLACK (1.0f + 0x1p-12f) /* alpha_rect's box: half-widths this much wider than rasterize_prep's */
#define PROJ_BOX_COND 0x1p-8f      /* alpha_rect: the box only where det >= this * A C ... */
#define PROJ_BOX_AC_MIN 0x1p-100f  /* ... and A C >= this (det computed on normal floats) */
#define PROJ_QUAT_NORM_MIN 1e-12f  /* below this |q| the rotation is undefined: cull (reference QUAT_NORM_MIN) */
#define DEPTH_KEY_CULLED 0xFFFFFFFFu /* sorts after every positive float's bits */
/* LLVM declines to inline the big helpers on its own (cost above its threshold): force it, one
   straight function per kernel. */
#define PROJ_INLINE inline __attribute__((always_inline))

/* Camera record (float32, built by reings.backends.opencl.backend.camera_record):
   [0..8] Rc row-major, [9..11] tc, [12] fx, [13] fy, [14] cx, [15] cy, [16..18] camera centre,
   [19] near, [20] lim_x_pos, [21] lim_x_neg, [22] lim_y_pos, [23] lim_y_neg */
#define CAM_RECORD 24
#define PACKED_FLOATS 16 /* floats per record of raster_prep_one */
#define V_PROJ 10 /* v record: v_mean2d xy, v_conic ABC, v_colour rgb, v_opacity, v_depth */
#define PROJ_VSCALE_ABOVE 0x1p60f /* the backward scales a cotangent row whose max |entry| exceeds this (cotangents_in) */
#include "densify.h" /* project_bwd with stats = 1: the densification statistics */

#define SH_C0 0.28209479177387814f
#define SH_C1 0.4886025119029199f
#define SH_C2_0 1.0925484305920792f
#define SH_C2_1 -1.0925484305920792f
#define SH_C2_2 0.31539156525252005f
#define SH_C2_3 -1.0925484305920792f
#define SH_C2_4 0.5462742152960396f
#define SH_C3_0 -0.5900435899266435f
#define SH_C3_1 2.890611442640554f
#define SH_C3_2 -0.4570457994644658f
#define SH_C3_3 0.3731763325901154f
#define SH_C3_4 -0.4570457994644658f
#define SH_C3_5 1.445305721320277f
#define SH_C3_6 -0.5900435899266435f

/* DROP_HASH(h, gid, key): DropGaussian's mask hash (docs/method.md §9): project_fwd keeps Gaussian
   gid iff the hash >= drop_threshold. murmur3's 32-bit finaliser (fmix32) of
   gid ^ (key * DROP_KEY_MUL), in uint arithmetic (wraps mod 2^32); h and gid are vu lanes (uint,
   uint8 or uint16), key a uint. The numpy twin is reings/backends/reference_drop.py drop_hash
   (tests/test_drop.py checks them bit for bit). */
#define DROP_KEY_MUL 0x9E3779B9u   /* 2^32 / golden ratio */
#define DROP_FMIX_MUL1 0x85EBCA6Bu /* fmix32 */
#define DROP_FMIX_MUL2 0xC2B2AE35u
#define DROP_HASH(h, gid, key)                      \
    do {                                            \
        (h) = (gid) ^ ((uint)(key) * DROP_KEY_MUL); \
        (h) ^= (h) >> 16;                           \
        (h) *= DROP_FMIX_MUL1;                      \
        (h) ^= (h) >> 13;                           \
        (h) *= DROP_FMIX_MUL2;                      \
        (h) ^= (h) >> 16;                           \
    } while (0)

/* ---------------------------------------------------------------------------------------------
   SH rows through local memory (PROJ_SH_STAGE, GPU schedule, SH_K > 1; docs/perf_notes.md §15).
   A Gaussian's SH row is SH_K * 3 consecutive floats, so a work-item per Gaussian reads and writes
   its coefficients at a stride of SH_K * 12 bytes: every warp-wide access touches 32 cache lines.
   Staged, a work-group of PROJ_WG Gaussians copies its block of rows (contiguous in memory) into
   local memory with consecutive work-items on consecutive words, each work-item reads its own row
   there (row stride SH_LSTRIDE, odd: no bank conflicts), and project_bwd writes v_sh into that
   row (after its last read of the coefficients) and copies the block out the same way. The same
   values in the same order: the same bits as the unstaged kernels.
   --------------------------------------------------------------------------------------------- */
#ifndef PROJ_SH_STAGE
#define PROJ_SH_STAGE 0
#endif
/* Where the SH coefficients are (kernel arguments sh_dc, dc_stride, sh_rest, rest_stride, rest_offset):
   word c of Gaussian g's row (c < 3 SH_K) is dc[g * dc_stride + c] for c < 3 (the DC coefficient) and
   rest[g * rest_stride + rest_offset + c - 3] after: the training state's sh_dc [N,1,3] and sh_rest
   [N,KMAX-1,3] read in place (strides 3 and 3 (KMAX - 1), offset 0: no packed copy per SH step), or one
   packed [N,SH_K,3] array (both pointers it, strides 3 SH_K, offset 3). */
typedef struct {
    __global const float *dc;
    __global const float *rest;
    int dc_stride, rest_stride, rest_offset;
} sh_in_t;
#define SH_ARGS                                                                              \
    __global const float *sh_dc, const int dc_stride, __global const float *sh_rest,          \
        const int rest_stride, const int rest_offset
#define SH_IN_OF_ARGS {sh_dc, sh_rest, dc_stride, rest_stride, rest_offset}
#if PROJ_SH_STAGE
#ifndef PROJ_WG
#error "PROJ_SH_STAGE needs PROJ_WG, the launch's work-group size"
#endif
#define SH_LSTRIDE ((SH_K * 3) | 1)
#define SH_SRC __local const float *
#define SH_DST __local float *
#define SH_AT(src, gid, i) ((src)[(i)]) /* src: the work-item's row */
#define SH_OUT(dst, i, x) ((dst)[(i)] = (x))
#define PROJ_ATTR __attribute__((reqd_work_group_size(PROJ_WG, 1, 1)))
#else
#define SH_SRC sh_in_t
#define SH_DST __global float *
#define SH_AT(src, gid, i)                                           \
    ((i) < 3 ? GATHER((src).dc, (gid) * (src).dc_stride + (i))      \
             : GATHER((src).rest, (gid) * (src).rest_stride + (src).rest_offset + ((i) - 3)))
#define SH_OUT(dst, i, x) GRAD_F(dst, SH_K * 3, i, x, 16) /* project_bwd_one only */
#define PROJ_ATTR
#endif

/* ---------------------------------------------------------------------------------------------
   lane types: vf / vi hold PROJ_VW Gaussians. Comparisons give masks (scalar 0/1, vector 0/-1);
   masks combine with & | ! and feed SEL() (select); ANY() reduces one.
   PoCL 3.0 (pocl-binary-distribution) calls its builtins rather than inlining them, spilling every live
   vector register around each call (docs/perf_notes.md §17): SEL and any8 (common.h), FABS and the stores
   to private arrays are written with plain operators (the same values: masks are 0 / -1 or 0 / 1).
   --------------------------------------------------------------------------------------------- */
#ifndef PROJ_VW
#define PROJ_VW 1
#endif
#if PROJ_VW == 8
typedef float8 vf;
typedef int8 vi;
typedef uint8 vu;
#define VLANES ((vi)(0, 1, 2, 3, 4, 5, 6, 7))
#define ANY(m) any8(m)
#define CVT_I(x) convert_int8(x)
#define AS_U(x) as_uint8(x)
#define AS_I(x) as_int8(x)
#define AS_F(x) as_float8(x)
#define GATHER(base, idx)                                                                         \
    ((vf)((base)[(idx).s0], (base)[(idx).s1], (base)[(idx).s2], (base)[(idx).s3], (base)[(idx).s4], \
          (base)[(idx).s5], (base)[(idx).s6], (base)[(idx).s7]))
#define GATHER_I(base, idx)                                                                       \
    ((vi)((base)[(idx).s0], (base)[(idx).s1], (base)[(idx).s2], (base)[(idx).s3], (base)[(idx).s4], \
          (base)[(idx).s5], (base)[(idx).s6], (base)[(idx).s7]))
#define STORE8(x, tmp)                                                                    \
    do {                                                                                  \
        (tmp)[0] = (x).s0; (tmp)[1] = (x).s1; (tmp)[2] = (x).s2; (tmp)[3] = (x).s3;       \
        (tmp)[4] = (x).s4; (tmp)[5] = (x).s5; (tmp)[6] = (x).s6; (tmp)[7] = (x).s7;       \
    } while (0)
#define STORE_F(x, tmp) STORE8(x, tmp)
#define VLOAD_F(k, p) vload8(k, p) /* the k-th PROJ_VW floats at p */
#define VFROM(t) ((vf)((t)[0], (t)[1], (t)[2], (t)[3], (t)[4], (t)[5], (t)[6], (t)[7])) /* lanes from t[0..7] */
#define STORE_I(x, tmp) STORE8(x, tmp)
#define STORE_U(x, tmp) STORE8(x, tmp)
#elif PROJ_VW == 16
typedef float16 vf;
typedef int16 vi;
typedef uint16 vu;
#define VLANES ((vi)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define ANY(m) any16(m)
#define CVT_I(x) convert_int16(x)
#define AS_U(x) as_uint16(x)
#define AS_I(x) as_int16(x)
#define AS_F(x) as_float16(x)
#define GATHER16_(T, base, idx)                                                                    \
    ((T)((base)[(idx).s0], (base)[(idx).s1], (base)[(idx).s2], (base)[(idx).s3], (base)[(idx).s4],  \
         (base)[(idx).s5], (base)[(idx).s6], (base)[(idx).s7], (base)[(idx).s8], (base)[(idx).s9],  \
         (base)[(idx).sa], (base)[(idx).sb], (base)[(idx).sc], (base)[(idx).sd], (base)[(idx).se],  \
         (base)[(idx).sf]))
#define GATHER(base, idx) GATHER16_(vf, base, idx)
#define GATHER_I(base, idx) GATHER16_(vi, base, idx)
#define STORE16(x, tmp)                                                                   \
    do {                                                                                  \
        (tmp)[0] = (x).s0; (tmp)[1] = (x).s1; (tmp)[2] = (x).s2; (tmp)[3] = (x).s3;       \
        (tmp)[4] = (x).s4; (tmp)[5] = (x).s5; (tmp)[6] = (x).s6; (tmp)[7] = (x).s7;       \
        (tmp)[8] = (x).s8; (tmp)[9] = (x).s9; (tmp)[10] = (x).sa; (tmp)[11] = (x).sb;     \
        (tmp)[12] = (x).sc; (tmp)[13] = (x).sd; (tmp)[14] = (x).se; (tmp)[15] = (x).sf;   \
    } while (0)
#define STORE_F(x, tmp) STORE16(x, tmp)
#define VLOAD_F(k, p) GLD_vf(k, p)
#define VFROM(t) ((vf)((t)[0], (t)[1], (t)[2], (t)[3], (t)[4], (t)[5], (t)[6], (t)[7], (t)[8], (t)[9], (t)[10], \
                       (t)[11], (t)[12], (t)[13], (t)[14], (t)[15]))
#define STORE_I(x, tmp) STORE16(x, tmp)
#define STORE_U(x, tmp) STORE16(x, tmp)
#elif PROJ_VW == 1
typedef float vf;
typedef int vi;
typedef uint vu;
#define VLANES 0
#define ANY(m) (m)
#define CVT_I(x) ((int)(x))
#define AS_U(x) as_uint(x)
#define AS_I(x) as_int(x)
#define AS_F(x) as_float(x)
#define GATHER(base, idx) ((base)[(idx)])
#define GATHER_I(base, idx) ((base)[(idx)])
#define STORE_F(x, tmp) ((tmp)[0] = (x))
#define VLOAD_F(k, p) ((p)[k])
#define STORE_I(x, tmp) ((tmp)[0] = (x))
#define STORE_U(x, tmp) ((tmp)[0] = (x))
#else
#error "PROJ_VW must be 1, 8 or 16"
#endif

/* Lane math without PoCL's library calls (REINGS_SCALAR_BUILTINS, common.h): clang's elementwise floor / ceil /
   max / min (llvm.floor, .ceil, .maxnum, .minnum: OpenCL's floor, ceil, fmax, fmin, NaN rule included) and sqrt
   lane by lane through __builtin_sqrtf (IEEE, correctly rounded; the vectorizer makes one vsqrtps of them); clamp
   is fmin(fmax(x, lo), hi), as OpenCL defines it. Each builtin call spilled the live vector registers around it
   (docs/perf_notes.md §17, §35). The same bytes either way (tests/test_scalar_builtins.py). */
#if REINGS_SCALAR_BUILTINS && defined(__has_builtin)
#if __has_builtin(__builtin_elementwise_floor) && __has_builtin(__builtin_elementwise_ceil) && \
    __has_builtin(__builtin_elementwise_max) && __has_builtin(__builtin_elementwise_min)
#define PROJ_LANE_BUILTINS 1
#endif
#endif
#ifndef PROJ_LANE_BUILTINS
#define PROJ_LANE_BUILTINS 0
#endif
#if PROJ_LANE_BUILTINS
#define VFLOOR(x) __builtin_elementwise_floor((vf)(x))
#define VCEIL(x) __builtin_elementwise_ceil((vf)(x))
#define VFMAX(a, b) __builtin_elementwise_max((vf)(a), (vf)(b))
#define VFMIN(a, b) __builtin_elementwise_min((vf)(a), (vf)(b))
#if PROJ_VW == 16
inline vf vsqrt_(vf x) {
    return (vf)(__builtin_sqrtf(x.s0), __builtin_sqrtf(x.s1), __builtin_sqrtf(x.s2), __builtin_sqrtf(x.s3),
                __builtin_sqrtf(x.s4), __builtin_sqrtf(x.s5), __builtin_sqrtf(x.s6), __builtin_sqrtf(x.s7),
                __builtin_sqrtf(x.s8), __builtin_sqrtf(x.s9), __builtin_sqrtf(x.sa), __builtin_sqrtf(x.sb),
                __builtin_sqrtf(x.sc), __builtin_sqrtf(x.sd), __builtin_sqrtf(x.se), __builtin_sqrtf(x.sf));
}
#elif PROJ_VW == 8
inline vf vsqrt_(vf x) {
    return (vf)(__builtin_sqrtf(x.s0), __builtin_sqrtf(x.s1), __builtin_sqrtf(x.s2), __builtin_sqrtf(x.s3),
                __builtin_sqrtf(x.s4), __builtin_sqrtf(x.s5), __builtin_sqrtf(x.s6), __builtin_sqrtf(x.s7));
}
#else
inline vf vsqrt_(vf x) { return __builtin_sqrtf(x); }
#endif
#define VSQRT(x) vsqrt_((vf)(x))
#else
#define VFLOOR(x) floor(x)
#define VCEIL(x) ceil(x)
#define VFMAX(a, b) fmax(a, b)
#define VFMIN(a, b) fmin(a, b)
#define VSQRT(x) sqrt(x)
#endif
#define VCLAMP(x, lo, hi) VFMIN(VFMAX(x, lo), hi)
#undef BOX_SQRT
#define BOX_SQRT(x) VSQRT(x) /* ALPHA_BOX_HALF_LN (common.h) on lanes */
/* Vector loads and stores of global rows (16-lane blocks, PROJ_BLOCK_IO; their 8- and 4-float heads): PoCL's vload16 /
   vstore16 are library calls too; with PROJ_LANE_BUILTINS plain accesses through 4-byte-aligned vector types
   (photometric.cl's LDV / STV), the same bytes. GLD_T / GST_T name the lane type T (vf, vi, vu). */
#if PROJ_VW == 16 && PROJ_LANE_BUILTINS
typedef float16 vf_u16_ __attribute__((aligned(4)));
typedef int16 vi_u16_ __attribute__((aligned(4)));
typedef uint16 vu_u16_ __attribute__((aligned(4)));
typedef float8 vf_u8_ __attribute__((aligned(4)));
typedef float4 vf_u4_ __attribute__((aligned(4)));
#define GLD_vf(k, p) (*(__global const vf_u16_ *)((p) + (size_t)16 * (k)))
#define GLD_vi(k, p) (*(__global const vi_u16_ *)((p) + (size_t)16 * (k)))
#define GLD_vu(k, p) (*(__global const vu_u16_ *)((p) + (size_t)16 * (k)))
#define GST_vf(x, k, p) (*(__global vf_u16_ *)((p) + (size_t)16 * (k)) = (x))
#define GST_vi(x, k, p) (*(__global vi_u16_ *)((p) + (size_t)16 * (k)) = (x))
#define GST_vu(x, k, p) (*(__global vu_u16_ *)((p) + (size_t)16 * (k)) = (x))
#define GLD8(p) (*(__global const vf_u8_ *)(p))
#define GST8(x, p) (*(__global vf_u8_ *)(p) = (x))
#define GLD4(p) (*(__global const vf_u4_ *)(p))
#define GST4(x, p) (*(__global vf_u4_ *)(p) = (x))
#define PST_vf(x, p) (*(__private vf_u16_ *)(p) = (x))
#else
#define GLD_vf(k, p) vload16(k, p)
#define GLD_vi(k, p) vload16(k, p)
#define GLD_vu(k, p) vload16(k, p)
#define GST_vf(x, k, p) vstore16(x, k, p)
#define GST_vi(x, k, p) vstore16(x, k, p)
#define GST_vu(x, k, p) vstore16(x, k, p)
#define GLD8(p) vload8(0, p)
#define GST8(x, p) vstore8(x, 0, p)
#define GLD4(p) vload4(0, p)
#define GST4(x, p) vstore4(x, 0, p)
#define PST_vf(x, p) vstore16(x, 0, p)
#endif

/* out[(g0 + l) * stride + off] = lane l of x, for the lanes that are real Gaussians */
#define SCATTER_F(out, stride, off, x)                                                   \
    do {                                                                                 \
        const vf x_ = (x); /* once: STORE_* names its argument per lane */             \
        float tmp_[PROJ_VW];                                                             \
        STORE_F(x_, tmp_);                                                               \
        for (int l_ = 0; l_ < nl; ++l_) (out)[(size_t)(g0 + l_) * (stride) + (off)] = tmp_[l_]; \
    } while (0)
#define SCATTER_I(out, stride, off, x)                                                   \
    do {                                                                                 \
        const vi x_ = (x); /* once: STORE_* names its argument per lane */             \
        int tmp_[PROJ_VW];                                                               \
        STORE_I(x_, tmp_);                                                               \
        for (int l_ = 0; l_ < nl; ++l_) (out)[(size_t)(g0 + l_) * (stride) + (off)] = tmp_[l_]; \
    } while (0)
#define SCATTER_U(out, stride, off, x)                                                   \
    do {                                                                                 \
        const vu x_ = (x); /* once: STORE_* names its argument per lane */             \
        uint tmp_[PROJ_VW];                                                              \
        STORE_U(x_, tmp_);                                                               \
        for (int l_ = 0; l_ < nl; ++l_) (out)[(size_t)(g0 + l_) * (stride) + (off)] = tmp_[l_]; \
    } while (0)

/* A gradient output of project_bwd (`grad_acc`, `grad_mask` in scope): out[row] = lane value (grad_acc 0),
   or out[row] = out[row] + lane value for the fields in grad_mask (grad_acc 1: a second backward added
   into held gradients, one IEEE add per element, as reference_state.grad_add; the other fields untouched) */
#define GRAD_F(out, stride, off, x, bit)                                                 \
    do {                                                                                 \
        const vf x_ = (x);                                                               \
        float tmp_[PROJ_VW];                                                             \
        STORE_F(x_, tmp_);                                                               \
        if (!grad_acc) {                                                                 \
            for (int l_ = 0; l_ < nl; ++l_) (out)[(size_t)(g0 + l_) * (stride) + (off)] = tmp_[l_]; \
        } else if (grad_mask & (bit)) {                                                  \
            for (int l_ = 0; l_ < nl; ++l_) {                                            \
                const size_t i_ = (size_t)(g0 + l_) * (stride) + (off);                  \
                (out)[i_] = (out)[i_] + tmp_[l_];                                        \
            }                                                                            \
        }                                                                                \
    } while (0)

/* ---------------------------------------------------------------------------------------------
   PROJ_BLOCK_IO (CPU schedule at 16 lanes where clang's __builtin_shufflevector exists: backend's
   PoCL builds; docs/perf_notes.md §32). A work-item's 16 Gaussians are 16 consecutive rows, so each
   [N, S] field of theirs is one block of 16 S floats: loaded as S vectors and deinterleaved by
   shuffles (lane l of component j is float S l + j of the block), stored the same way backwards,
   and rows of a run-time stride (the SH coefficients, the [N, 10] cotangents) loaded as 16 row
   vectors and transposed. The per-lane code gathered one float per lane (an index extraction, a
   load and an insert per float). The same floats move either way, so every output keeps its bits;
   a work-item takes the blocks only when it is full and another row follows it (`blk`, BLOCKS: a row
   vector reads at most one row past its own), else the per-lane code: only the last work-item does.
   A row vector of rows_in reads 16 floats from column offset + 16 b, so "one row past" needs a stride of at least
   15 or 2 stride >= offset + 16 (every call below: strides 10, 3 SH_K >= 12 and 45; stride 3 deinterleaves).
   --------------------------------------------------------------------------------------------- */
#ifndef PROJ_BLOCK_IO /* default: on where it can be */
#if PROJ_VW == 16 && REINGS_CLANG_BUILTINS && defined(__has_builtin)
#if __has_builtin(__builtin_shufflevector)
#define PROJ_BLOCK_IO 1
#endif
#endif
#endif
#ifndef PROJ_BLOCK_IO
#define PROJ_BLOCK_IO 0
#endif
#if PROJ_BLOCK_IO
#if PROJ_VW != 16
#error "PROJ_BLOCK_IO needs PROJ_VW 16"
#endif
#define BLOCKS(n) (g0 + PROJ_VW < (n)) /* the work-item's lanes as blocks: full, and a row after them */
#define L16_(F, S, k) F(S, k, 0), F(S, k, 1), F(S, k, 2), F(S, k, 3), F(S, k, 4), F(S, k, 5), F(S, k, 6), \
    F(S, k, 7), F(S, k, 8), F(S, k, 9), F(S, k, 10), F(S, k, 11), F(S, k, 12), F(S, k, 13), F(S, k, 14), F(S, k, 15)
#define SHUF_(a, b, F, S, k) __builtin_shufflevector(a, b, L16_(F, S, k))
/* deinterleave: lane l of component j is float f = S l + j of the block (vectors v0 v1 | v2 v3) */
#define DI_A_(S, j, l) ((S) * (l) + (j) < 32 ? (S) * (l) + (j) : -1)
#define DI_B_(S, j, l) ((S) * (l) + (j) >= 32 ? (S) * (l) + (j) - 32 : -1)
#define DI_C_(S, j, l) ((S) * (l) + (j) < 32 ? (l) : 16 + (l))
#define DI_J_(S, j, v, out)                                                                     \
    if ((j) < (S)) (out)[j] = SHUF_(SHUF_(v[0], v[1], DI_A_, S, j), SHUF_(v[2], v[3], DI_B_, S, j), DI_C_, S, j)
/* out[j] (j < S, S in 2..4) = lanes S l + j of the 16 S floats at p */
#define DEINTERLEAVE(S, p, out)                                                                 \
    do {                                                                                        \
        vf v_[4];                                                                               \
        for (int k_ = 0; k_ < 4; ++k_) v_[k_] = GLD_vf(k_ < (S) ? k_ : (S) - 1, p);           \
        DI_J_(S, 0, v_, out); DI_J_(S, 1, v_, out); DI_J_(S, 2, v_, out); DI_J_(S, 3, v_, out); \
    } while (0)
/* interleave: float f = 16 k + m of the block is lane f / S of component f % S (components c0 c1 | c2 c3) */
#define IL_J_(S, k, m) ((16 * (k) + (m)) % (S))
#define IL_L_(S, k, m) ((16 * (k) + (m)) / (S))
#define IL_OK_(S, k, m) (IL_L_(S, k, m) < 16) /* false only in the dead code of a block vector k >= S */
#define IL_A_(S, k, m) (IL_OK_(S, k, m) && IL_J_(S, k, m) < 2 ? 16 * IL_J_(S, k, m) + IL_L_(S, k, m) : -1)
#define IL_B_(S, k, m) (IL_OK_(S, k, m) && IL_J_(S, k, m) >= 2 ? 16 * (IL_J_(S, k, m) - 2) + IL_L_(S, k, m) : -1)
#define IL_C_(S, k, m) (IL_J_(S, k, m) < 2 ? (m) : 16 + (m))
/* block vector k (k < S) of the components c[0..S-1] (c: an array of 4, the unused ones any vector) */
#define INTERLEAVE_K(S, k, c) SHUF_(SHUF_(c[0], c[1], IL_A_, S, k), SHUF_(c[2], c[3], IL_B_, S, k), IL_C_, S, k)
/* the 16 rows of an [N, S] field (S in 1..4) from its components vals[0..S-1] (T: vf or vi): o[S l + j] =
   lane l of vals[j], or o[...] + that (acc) */
#define BLOCK_OUT_K_(T, S, k, c, o, acc)                                                        \
    if ((k) < (S)) {                                                                            \
        const T y_ = INTERLEAVE_K(S, k, c);                                                     \
        GST_##T((acc) ? GLD_##T(k, o) + y_ : y_, k, o);                                         \
    }
#define BLOCK_OUT(T, S, vals, o, acc)                                                           \
    do {                                                                                        \
        const T blk_c_[4] = {(vals)[0], (vals)[(S) > 1 ? 1 : 0], (vals)[(S) > 2 ? 2 : 0],       \
                             (vals)[(S) > 3 ? 3 : 0]};                                          \
        BLOCK_OUT_K_(T, S, 0, blk_c_, o, acc) BLOCK_OUT_K_(T, S, 1, blk_c_, o, acc)             \
        BLOCK_OUT_K_(T, S, 2, blk_c_, o, acc) BLOCK_OUT_K_(T, S, 3, blk_c_, o, acc)             \
    } while (0)

/* 16 x 16 transpose in place: m[r] lane c <- m[c] lane r (four butterfly stages; stage s swaps bit s
   of the row and the lane index) */
#define TR_LO_(S, k, c) (((c) & (S)) ? 16 + ((c) ^ (S)) : (c))
#define TR_HI_(S, k, c) (((c) & (S)) ? 16 + (c) : ((c) ^ (S)))
#define TR_STAGE_(m, S)                                                                         \
    for (int i_ = 0; i_ < 16; ++i_)                                                             \
        if (!(i_ & (S))) {                                                                      \
            const vf a_ = m[i_], b_ = m[i_ | (S)];                                              \
            m[i_] = SHUF_(a_, b_, TR_LO_, S, 0);                                                \
            m[i_ | (S)] = SHUF_(a_, b_, TR_HI_, S, 0);                                          \
        }
PROJ_INLINE void transpose16(vf *m) {
    TR_STAGE_(m, 1);
    TR_STAGE_(m, 2);
    TR_STAGE_(m, 4);
    TR_STAGE_(m, 8);
}

/* out[c] (c < cols) = lane l: p[l stride + c], the 16 rows at stride `stride` (row vectors of 16 floats:
   a row is read up to 15 floats past column cols - 1) */
PROJ_INLINE void rows_in(__global const float *p, const int stride, const int cols, vf *out) {
    for (int b = 0; b < cols; b += 16) {
        vf m[16];
        for (int l = 0; l < 16; ++l) m[l] = GLD_vf(0, p + (size_t)l * stride + b);
        transpose16(m);
        for (int c = 0; c < 16 && b + c < cols; ++c) out[b + c] = m[c];
    }
}

/* the first cnt (<= 16, a constant) floats of r to p (acc: added to what is there) */
PROJ_INLINE void store_head(const vf r, const int cnt, __global float *p, const int acc) {
    if (cnt == 16) { GST_vf(acc ? GLD_vf(0, p) + r : r, 0, p); return; }
    int o = 0;
    if (cnt & 8) { const float8 x = r.lo; GST8(acc ? GLD8(p) + x : x, p); o = 8; }
    if (cnt & 4) { const float4 x = (o ? r.hi.lo : r.lo.lo); GST4(acc ? GLD4(p + o) + x : x, p + o); o += 4; }
    float t[16];
    PST_vf(r, t);
    for (int i = o; i < cnt; ++i) p[i] = acc ? p[i] + t[i] : t[i];
}

/* p[l stride + c] = lane l of in[c] (c < cols; acc: added), the 16 rows at stride >= cols */
PROJ_INLINE void rows_out(const vf *in, const int cols, __global float *p, const int stride, const int acc) {
    for (int b = 0; b < cols; b += 16) {
        vf m[16];
        for (int c = 0; c < 16; ++c) m[c] = b + c < cols ? in[b + c] : (vf)0.0f;
        transpose16(m);
        const int w = min(16, cols - b);
        for (int l = 0; l < 16; ++l) store_head(m[l], w, p + (size_t)l * stride + b, acc);
    }
}
#endif

/* A work-item's rows of an [N, S] output from its S component lanes vals[]: blocks with PROJ_BLOCK_IO where `blk`,
   else per lane (SCAT: SCATTER_F / _I / _U); GRAD_ROWS likewise with GRAD_F's semantics (grad_acc, grad_mask) */
#if PROJ_BLOCK_IO
#define OUT_ROWS(T, SCAT, out, S, vals)                                                         \
    do {                                                                                        \
        if (blk) BLOCK_OUT(T, S, vals, (out) + (size_t)(S) * g0, 0);                            \
        else for (int j_ = 0; j_ < (S); ++j_) SCAT(out, S, j_, (vals)[j_]);                     \
    } while (0)
#define GRAD_ROWS(out, S, vals, bit)                                                            \
    do {                                                                                        \
        if (!blk) { for (int j_ = 0; j_ < (S); ++j_) GRAD_F(out, S, j_, (vals)[j_], bit); }     \
        else if (!grad_acc) BLOCK_OUT(vf, S, vals, (out) + (size_t)(S) * g0, 0);                \
        else if (grad_mask & (bit)) BLOCK_OUT(vf, S, vals, (out) + (size_t)(S) * g0, 1);        \
    } while (0)
/* the SH gradient rows ([N, SH_K, 3] packed, stride 3 SH_K) from vals[3 SH_K] */
#if SH_K == 1
#define SH_ROWS(out, vals) GRAD_ROWS(out, 3, vals, 16) /* SH_OUT is GRAD_F at stride 3 */
#else
#define SH_ROWS(out, vals)                                                                      \
    do {                                                                                        \
        if (!blk) { for (int c_ = 0; c_ < SH_K * 3; ++c_) SH_OUT(out, c_, (vals)[c_]); }        \
        else if (!grad_acc) rows_out(vals, SH_K * 3, (out) + (size_t)g0 * (SH_K * 3), SH_K * 3, 0); \
        else if (grad_mask & 16) rows_out(vals, SH_K * 3, (out) + (size_t)g0 * (SH_K * 3), SH_K * 3, 1); \
    } while (0)
#endif
#else
#define SH_ROWS(out, vals) for (int c_ = 0; c_ < SH_K * 3; ++c_) SH_OUT(out, c_, (vals)[c_])
#define OUT_ROWS(T, SCAT, out, S, vals) for (int j_ = 0; j_ < (S); ++j_) SCAT(out, S, j_, (vals)[j_])
#define GRAD_ROWS(out, S, vals, bit) for (int j_ = 0; j_ < (S); ++j_) GRAD_F(out, S, j_, (vals)[j_], bit)
#endif
#define SH_ROWS_ZERO(out)                                                                       \
    do {                                                                                        \
        vf z_[SH_K * 3];                                                                        \
        for (int c_ = 0; c_ < SH_K * 3; ++c_) z_[c_] = 0.0f;                                    \
        SH_ROWS(out, z_);                                                                       \
    } while (0)

/* |x| <= FLT_MAX is false for NaN and +-Inf */
#define FABS(x) AS_F(AS_U(x) & 0x7fffffffu) /* fabs(x) */
#define FINITE(x) (FABS(x) <= FLT_MAX)

/* SH basis values at the unit direction (x, y, z), order of 3DGS (docs/method.md §5.5) */
PROJ_INLINE void sh_basis(vf x, vf y, vf z, vf *b) {
    b[0] = SH_C0;
#if SH_K > 1
    b[1] = -SH_C1 * y;
    b[2] = SH_C1 * z;
    b[3] = -SH_C1 * x;
#endif
#if SH_K > 4
    vf xx = x * x, yy = y * y, zz = z * z;
    b[4] = SH_C2_0 * x * y;
    b[5] = SH_C2_1 * y * z;
    b[6] = SH_C2_2 * (2.0f * zz - xx - yy);
    b[7] = SH_C2_3 * x * z;
    b[8] = SH_C2_4 * (xx - yy);
#endif
#if SH_K > 9
    b[9] = SH_C3_0 * y * (3.0f * xx - yy);
    b[10] = SH_C3_1 * x * y * z;
    b[11] = SH_C3_2 * y * (4.0f * zz - xx - yy);
    b[12] = SH_C3_3 * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
    b[13] = SH_C3_4 * x * (4.0f * zz - xx - yy);
    b[14] = SH_C3_5 * z * (xx - yy);
    b[15] = SH_C3_6 * x * (xx - 3.0f * yy);
#endif
}

/* The raw fields of a work-item's lanes: PROJ_BLOCK_IO loads them once (`load_raw`: blocks, or the per-lane
   gathers for a work-item without `blk`); otherwise each use gathers its lanes (IN_*), as before. */
#if PROJ_BLOCK_IO
typedef struct {
    vf mu[3], q[4], ls[3], ol;
    vf sh[SH_K * 3];
} raw_t;
#define RAW_PARAM , const raw_t *raw
#define RAW_ARG , raw
#define IN_OL (raw->ol)
#define IN_MU(i) (raw->mu[i])
#define IN_LS(i) (raw->ls[i])
#define IN_Q(i) (raw->q[i])
#define IN_SH(i) (raw->sh[i])
PROJ_INLINE void load_raw(raw_t *r, const int blk, const int g0, const vi gid, __global const float *means,
                          __global const float *quats, __global const float *log_scales,
                          __global const float *opacity_logits, const sh_in_t sh) {
    if (blk) {
        DEINTERLEAVE(3, means + 3 * (size_t)g0, r->mu);
        DEINTERLEAVE(4, quats + 4 * (size_t)g0, r->q);
        DEINTERLEAVE(3, log_scales + 3 * (size_t)g0, r->ls);
        r->ol = GLD_vf(0, opacity_logits + g0);
        if (sh.dc_stride == 3) {
            DEINTERLEAVE(3, sh.dc + 3 * (size_t)g0, r->sh);
        } else {
            rows_in(sh.dc + (size_t)g0 * sh.dc_stride, sh.dc_stride, 3, r->sh);
        }
#if SH_K > 1
        rows_in(sh.rest + (size_t)g0 * sh.rest_stride + sh.rest_offset, sh.rest_stride, 3 * (SH_K - 1), r->sh + 3);
#endif
        return;
    }
    for (int i = 0; i < 3; ++i) {
        r->mu[i] = GATHER(means, 3 * gid + i);
        r->ls[i] = GATHER(log_scales, 3 * gid + i);
    }
    for (int i = 0; i < 4; ++i) r->q[i] = GATHER(quats, 4 * gid + i);
    r->ol = GATHER(opacity_logits, gid);
    for (int i = 0; i < SH_K * 3; ++i) r->sh[i] = SH_AT(sh, gid, i);
}
#else
#define RAW_PARAM
#define RAW_ARG
#define IN_OL GATHER(opacity_logits, gid)
#define IN_MU(i) GATHER(means, 3 * gid + (i))
#define IN_LS(i) GATHER(log_scales, 3 * gid + (i))
#define IN_Q(i) GATHER(quats, 4 * gid + (i))
#define IN_SH(i) SH_AT(sh, gid, i)
#endif

/* Everything project_fwd computes for PROJ_VW Gaussians, kept for the backward. */
typedef struct {
    vf qn[4];      /* normalised quaternion (w, x, y, z) */
    vf qnorm;      /* |q| */
    vf R[9];       /* rotation of qn, row-major */
    vf s[3];       /* exp(log_scales) */
    vf M[9];       /* R S */
    vf t[3];       /* camera-space mean */
    vf txc, tyc;   /* clamped t_x, t_y (J is evaluated there) */
    vi clx, cly;   /* clamp active (mask) */
    vf J[6];       /* 2x3: J00 J01 J02 / J10 J11 J12 */
    vf Sc[9];      /* Rc Sigma Rc^T */
    vf a, b, c;    /* Sigma2d (with EPS2D) */
    vf A, B, C;    /* conic */
    vf u, v;
    vf radius;
    vf rect[4];    /* tile rect, integral values in float (clamped to the grid) */
    vf dir[3];     /* unit direction mean - campos */
    vf dnorm;      /* |mean - campos| */
    vf raw[3];     /* SH sum + 0.5, before the clamp */
} proj_t;

/* Forward math for the lanes `gid` (indices already clamped into [0, n)). Returns the mask of the
   lanes that stay visible; culled lanes hold garbage (possibly inf / NaN), never used. */
PROJ_INLINE vi project_one(vi gid, __global const float *means, __global const float *quats,
                           __global const float *log_scales, __global const float *opacity_logits,
                           SH_SRC sh, __constant const float *cam, int width, int height,
                           proj_t *p RAW_PARAM) {
    /* every raw field finite */
    vi ok = FINITE(IN_OL);
    vf mu[3];
    for (int i = 0; i < 3; ++i) {
        mu[i] = IN_MU(i);
        ok &= FINITE(mu[i]) & FINITE(IN_LS(i));
    }
    vf q[4];
    for (int i = 0; i < 4; ++i) {
        q[i] = IN_Q(i);
        ok &= FINITE(q[i]);
    }
    for (int i = 0; i < SH_K * 3; ++i) ok &= FINITE(IN_SH(i));

    /* camera-space mean and near cull */
    for (int i = 0; i < 3; ++i)
        p->t[i] = cam[3 * i] * mu[0] + cam[3 * i + 1] * mu[1] + cam[3 * i + 2] * mu[2] + cam[9 + i];
    const float near = cam[19];
    ok &= (p->t[2] > near) & FINITE(p->t[2]);  /* behind or at the near plane (NaN fails) */

    /* quaternion -> rotation; |q| computed scaled by max |q_i| so that neither huge nor tiny
       (denormal) components overflow or underflow the sum of squares */
    vf qmax = VFMAX(VFMAX(FABS(q[0]), FABS(q[1])), VFMAX(FABS(q[2]), FABS(q[3])));
    ok &= qmax > 0.0f;
    vf iqm = 1.0f / qmax;
    vf w = q[0] * iqm, x = q[1] * iqm, y = q[2] * iqm, z = q[3] * iqm;
    vf n2 = w * w + x * x + y * y + z * z; /* in [1, 4] */
    vf qn = VSQRT(n2);
    p->qnorm = qmax * qn;
    ok &= p->qnorm >= PROJ_QUAT_NORM_MIN;  /* undefined rotation */
    w /= qn; x /= qn; y /= qn; z /= qn;
    p->qn[0] = w; p->qn[1] = x; p->qn[2] = y; p->qn[3] = z;
    vf *R = p->R;
    R[0] = 1.0f - 2.0f * (y * y + z * z); R[1] = 2.0f * (x * y - w * z); R[2] = 2.0f * (x * z + w * y);
    R[3] = 2.0f * (x * y + w * z); R[4] = 1.0f - 2.0f * (x * x + z * z); R[5] = 2.0f * (y * z - w * x);
    R[6] = 2.0f * (x * z - w * y); R[7] = 2.0f * (y * z + w * x); R[8] = 1.0f - 2.0f * (x * x + y * y);

    for (int j = 0; j < 3; ++j) p->s[j] = exp(IN_LS(j));
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p->M[3 * i + j] = R[3 * i + j] * p->s[j];

    /* world covariance Sigma = M M^T, then camera covariance Sc = Rc Sigma Rc^T = (Rc M)(Rc M)^T */
    vf W[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            W[3 * i + j] = cam[3 * i] * p->M[j] + cam[3 * i + 1] * p->M[3 + j] + cam[3 * i + 2] * p->M[6 + j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            p->Sc[3 * i + j] = W[3 * i] * W[3 * j] + W[3 * i + 1] * W[3 * j + 1] + W[3 * i + 2] * W[3 * j + 2];

    /* projection with the gsplat guard band */
    const float fx = cam[12], fy = cam[13], cx = cam[14], cy = cam[15];
    const vf tz = p->t[2];
    const vf rz = 1.0f / tz;
    vf xz = p->t[0] * rz, yz = p->t[1] * rz;
    p->clx = !((xz >= -cam[21]) & (xz <= cam[20]));
    p->cly = !((yz >= -cam[23]) & (yz <= cam[22]));
    p->txc = tz * VCLAMP(xz, -cam[21], cam[20]);
    p->tyc = tz * VCLAMP(yz, -cam[23], cam[22]);
    p->u = fx * p->t[0] * rz + cx;
    p->v = fy * p->t[1] * rz + cy;
    vf *J = p->J;
    J[0] = fx * rz; J[1] = 0.0f; J[2] = -fx * p->txc * rz * rz;
    J[3] = 0.0f; J[4] = fy * rz; J[5] = -fy * p->tyc * rz * rz;

    /* Sigma2d = J Sc J^T (+ EPS2D on the diagonal) */
    vf JS[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            JS[3 * i + j] = J[3 * i] * p->Sc[j] + J[3 * i + 1] * p->Sc[3 + j] + J[3 * i + 2] * p->Sc[6 + j];
    p->a = JS[0] * J[0] + JS[1] * J[1] + JS[2] * J[2] + PROJ_EPS2D;
    p->b = JS[0] * J[3] + JS[1] * J[4] + JS[2] * J[5];
    p->c = JS[3] * J[3] + JS[4] * J[4] + JS[5] * J[5] + PROJ_EPS2D;
    ok &= FINITE(p->a) & FINITE(p->b) & FINITE(p->c);
    /* det, conic and lambda_max computed on Sigma2d / m, m = max(a, c) >= EPS2D, so that a huge
       but representable Sigma2d does not overflow det = ac - b^2 */
    const vf m = VFMAX(p->a, p->c), im = 1.0f / m;
    const vf a1 = p->a * im, b1 = p->b * im, c1 = p->c * im;
    const vf det1 = a1 * c1 - b1 * b1;
    ok &= det1 > 0.0f;  /* degenerate (NaN fails) */
    const vf idet = 1.0f / (det1 * m);
    p->A = c1 * idet; p->B = -b1 * idet; p->C = a1 * idet;

    /* radius and tile rectangle: lambda_max = m (mid1 + sqrt(max(0.1 / m^2, mid1^2 - det1))) */
    vf mid1 = 0.5f * (a1 + c1);
    vf lam = m * (mid1 + VSQRT(VFMAX(PROJ_LAMBDA_FLOOR * im * im, mid1 * mid1 - det1)));
    vf r = VCEIL(PROJ_SIGMAS * VSQRT(lam));
    ok &= (lam <= FLT_MAX) & FINITE(p->u) & FINITE(p->v) & FINITE(p->A) & FINITE(p->B) & FINITE(p->C);
    p->radius = r;
    const int tiles_x = (width + TILE_SIZE - 1) / TILE_SIZE, tiles_y = (height + TILE_SIZE - 1) / TILE_SIZE;
    const float inv_tile = 1.0f / (float)TILE_SIZE;
    /* clamped in float (a huge r would overflow an int); integral values */
    p->rect[0] = VCLAMP(VFLOOR((p->u - r) * inv_tile), 0.0f, (float)tiles_x);
    p->rect[1] = VCLAMP(VFLOOR((p->v - r) * inv_tile), 0.0f, (float)tiles_y);
    p->rect[2] = VCLAMP(VCEIL((p->u + r) * inv_tile), 0.0f, (float)tiles_x);
    p->rect[3] = VCLAMP(VCEIL((p->v + r) * inv_tile), 0.0f, (float)tiles_y);
    ok &= (p->rect[2] > p->rect[0]) & (p->rect[3] > p->rect[1]);  /* off screen (NaN fails) */

    /* SH colour at the view direction */
    vf d[3] = {mu[0] - cam[16], mu[1] - cam[17], mu[2] - cam[18]};
    vf dn = VSQRT(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    p->dnorm = dn;
    vf idn = SEL((vf)0.0f, 1.0f / dn, dn > 0.0f);
    for (int i = 0; i < 3; ++i) p->dir[i] = d[i] * idn;
    vf bas[SH_K];
    sh_basis(p->dir[0], p->dir[1], p->dir[2], bas);
    for (int ch = 0; ch < 3; ++ch) {
        vf acc = 0.0f;
        for (int k = 0; k < SH_K; ++k) acc += bas[k] * IN_SH(3 * k + ch);
        p->raw[ch] = acc + 0.5f;
    }
    ok &= FINITE(p->raw[0]) & FINITE(p->raw[1]) & FINITE(p->raw[2]) & FINITE(p->t[0]) & FINITE(p->t[1]);
    return ok;
}

/* The opacity-aware tile rect: p->rect (the 3-sigma tiles) cut to the tiles that the alpha box of
   opacity o overlaps (common.h: outside it alpha = o exp(power) < ALPHA_MIN); empty (all zeros)
   where o < 1/255. The rasterizer blends a (pixel, Gaussian) pair only inside rasterize_prep's box
   and where alpha >= ALPHA_MIN, so every intersection this removes blended nothing: it added exact
   zeros to its per-intersection records (gradients, importance) and nothing to any pixel, and
   `last` counts positions in the tile's list in the forward and the backward alike. The images,
   depths, alphas and every gradient are therefore those of the 3-sigma rect (up to the sign of a
   zero sum), and no switch is needed. Pixels are tested against rasterize_prep's box computed from
   the same stored floats (u, v, A, B, C, o), so the cut must contain that box:
     - same formula (ALPHA_BOX_HALF_LN) with the half-widths PROJ_BOX_SLACK (2^-12) wider, which
       absorbs the rounding differences between the two kernels (FMA contraction of det, vector
       and scalar log / sqrt: < 2^-15 relative where det >= 2^-8 A C);
     - the box only where it is well conditioned: lo = 255 o finite, A, C > 0, det > 0 finite,
       det >= PROJ_BOX_COND A C and A C >= PROJ_BOX_AC_MIN; elsewhere (nearly degenerate conics,
       where float rounding of det is large, and the non positive definite case, where
       rasterize_prep has no box) the 3-sigma rect stays;
     - lo < 1 (computed from the same float o as rasterize_prep): rasterize_prep's box is empty,
       the Gaussian is never blended: empty rect. It stays visible (radii > 0: the densification
       statistics count it as before); with no intersection its gradients are zero, as before.
   Pixel columns [ceil(u - ex - 0.5), floor(u + ex - 0.5)] (rasterize_prep's expressions), tile
   columns [floor(first / 16), floor(last / 16) + 1); rows likewise with v, ey. gsplat cuts its
   per-axis extents the same way (ProjectionEWA3DGSFused.cu: extend = min(3.33, sqrt(2 ln(o /
   ALPHA_THRESHOLD))), culling o < ALPHA_THRESHOLD; docs/method.md §5.3). */
PROJ_INLINE vf alpha_rect(proj_t *p, vf o) {
    const vf A = p->A, B = p->B, C = p->C;
    const vf lo = ALPHA_BOX_LO(o);
    const vf ac = A * C;
    const vf det = ac - B * B;
    const vi box = (lo >= 1.0f) & FINITE(lo) & (A > 0.0f) & (C > 0.0f) & (det > 0.0f) & FINITE(det) &
                   (det >= PROJ_BOX_COND * ac) & (ac >= PROJ_BOX_AC_MIN);
    const vf ln_lo = log(lo);
    const vf ex = ALPHA_BOX_HALF_LN(ln_lo, C, det, ALPHA_BOX_REL * PROJ_BOX_SLACK);
    const vf ey = ALPHA_BOX_HALF_LN(ln_lo, A, det, ALPHA_BOX_REL * PROJ_BOX_SLACK);
    const float inv_tile = 1.0f / (float)TILE_SIZE;
    const vf bx0 = VFLOOR(VCEIL(p->u - ex - 0.5f) * inv_tile), bx1 = VFLOOR(VFLOOR(p->u + ex - 0.5f) * inv_tile) + 1.0f;
    const vf by0 = VFLOOR(VCEIL(p->v - ey - 0.5f) * inv_tile), by1 = VFLOOR(VFLOOR(p->v + ey - 0.5f) * inv_tile) + 1.0f;
    vf r[4];
    r[0] = SEL(p->rect[0], VFMAX(p->rect[0], bx0), box);
    r[1] = SEL(p->rect[1], VFMAX(p->rect[1], by0), box);
    r[2] = SEL(p->rect[2], VFMIN(p->rect[2], bx1), box);
    r[3] = SEL(p->rect[3], VFMIN(p->rect[3], by1), box);
    /* empty: o < 1/255, or the box misses the 3-sigma tiles (lo NaN or inf: no box, rect kept) */
    const vi empty = (lo < 1.0f) | !((r[2] > r[0]) & (r[3] > r[1]));
    for (int i = 0; i < 4; ++i) p->rect[i] = SEL(r[i], (vf)0.0f, empty);
    return ln_lo; /* log(ALPHA_BOX_LO(o)): raster_prep_lanes takes it too */
}

#if PROJ_BLOCK_IO
/* raster_prep_one (common.h) on a work-item's 16 lanes, from the floats project_fwd just stored (u, v, A, B, C, o,
   r, g, b, z) and ln_lo = log(ALPHA_BOX_LO(o)) where o is the stored opacity (elsewhere any value: those lanes
   have no box): the same operations lane by lane (its branches as selects; PoCL's vector log is its scalar log
   per lane), the 16 records written as one transposed block (packed + 16 g0). */
PROJ_INLINE void raster_prep_lanes(const vf *f10, const vf ln_lo, __global float *rec) {
    vf f[16];
    for (int i = 0; i < 10; ++i) f[i] = f10[i];
    const vf u = f[0], v = f[1], A = f[2], B = f[3], C = f[4], lo = ALPHA_BOX_LO(f[5]);
    const vi has = (lo >= 1.0f) & FINITE(u) & FINITE(v) & FINITE(lo);
    const vf det = A * C - B * B;
    const vi pd = (det > 0.0f) & (A > 0.0f) & (C > 0.0f) & FINITE(det);
    const vf ex = SEL((vf)1e7f, VFMIN(ALPHA_BOX_HALF_LN(ln_lo, C, det, ALPHA_BOX_REL), 1e7f), pd);
    const vf ey = SEL((vf)1e7f, VFMIN(ALPHA_BOX_HALF_LN(ln_lo, A, det, ALPHA_BOX_REL), 1e7f), pd);
    f[10] = SEL((vf)1.0f, VCLAMP(VCEIL(u - ex - 0.5f), -2.0f, 1e7f), has); /* empty box: (1, 0, 1, 0) */
    f[11] = SEL((vf)0.0f, VCLAMP(VFLOOR(u + ex - 0.5f), -2.0f, 1e7f), has);
    f[12] = SEL((vf)1.0f, VCLAMP(VCEIL(v - ey - 0.5f), -2.0f, 1e7f), has);
    f[13] = SEL((vf)0.0f, VCLAMP(VFLOOR(v + ey - 0.5f), -2.0f, 1e7f), has);
    f[14] = SEL((vf)0.0f, ALPHA_CUT_LN(ln_lo), has);
    f[15] = 0.0f;
    rows_out(f, 16, rec, 16, 0);
}
#endif

/* Lanes of work-item `wi`: g0 = first gid, nl = how many are real, gid = clamped lane gids */
#define LANES(n)                                                        \
    const int g0 = (int)get_global_id(0) * PROJ_VW;                     \
    if (g0 >= (n)) return;                                              \
    const int nl = min(PROJ_VW, (n) - g0);                              \
    const vi gid = min((vi)g0 + VLANES, (vi)((n) - 1));                 \
    const vi lane_ok = ((vi)g0 + VLANES) < (vi)(n)

#if PROJ_SH_STAGE
#if PROJ_VW != 1
#error "PROJ_SH_STAGE needs PROJ_VW 1 (a work-item per Gaussian)"
#endif
/* The work-group's block of SH rows -> local memory (row stride SH_LSTRIDE); every work-item calls
   it (a barrier inside). */
PROJ_INLINE void sh_stage_in(const int n, const sh_in_t sh, __local float *rows) {
    const int lid = (int)get_local_id(0), base = (int)get_group_id(0) * PROJ_WG;
    const int nr = min(PROJ_WG, n - base);
    /* two branch-free copies, each contiguous in its source (strides 3 and 3 (KMAX - 1)): the DC
       coefficients, then the others (a per-word choice of source doubled the loads: call 5) */
    __global const float *dc = sh.dc + (size_t)base * sh.dc_stride; /* the block's first row: 32-bit offsets after */
    for (int i = lid; i < nr * 3; i += PROJ_WG) {
        const int r = i / 3, c = i - 3 * r;
        rows[r * SH_LSTRIDE + c] = dc[r * sh.dc_stride + c];
    }
#if SH_K > 1
    __global const float *rest = sh.rest + (size_t)base * sh.rest_stride + sh.rest_offset;
    for (int i = lid; i < nr * (SH_K * 3 - 3); i += PROJ_WG) {
        const int r = i / (SH_K * 3 - 3), c = i - r * (SH_K * 3 - 3);
        rows[r * SH_LSTRIDE + 3 + c] = rest[r * sh.rest_stride + c];
    }
#endif
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* The block of rows in local memory -> v_sh (acc: added into it, as GRAD_F; nothing when acc and the
   SH are not asked for); every work-item calls it (a barrier first). */
PROJ_INLINE void sh_stage_out(const int n, __local const float *rows, __global float *v_sh, const int acc,
                              const int wanted) {
    barrier(CLK_LOCAL_MEM_FENCE);
    if (acc && !wanted) return;
    const int lid = (int)get_local_id(0), base = (int)get_group_id(0) * PROJ_WG;
    const int words = min(PROJ_WG, n - base) * (SH_K * 3);
    for (int i = lid; i < words; i += PROJ_WG) {
        const int r = i / (SH_K * 3);
        const float x = rows[r * SH_LSTRIDE + (i - r * (SH_K * 3))];
        const size_t at = (size_t)base * (SH_K * 3) + i;
        v_sh[at] = acc ? v_sh[at] + x : x;
    }
}
#endif

/* Forward projection, one work-item per PROJ_VW Gaussians. DropGaussian: drop_threshold 0 keeps
   every Gaussian (the host then passes drop_scale 1: the outputs are those without the option);
   the host never combines a drop with opacity_override. */
__kernel PROJ_ATTR void project_fwd(const int n,
                          __global const float *means,          /* [N, 3] */
                          __global const float *quats,          /* [N, 4] (w, x, y, z) */
                          __global const float *log_scales,     /* [N, 3] */
                          __global const float *opacity_logits, /* [N] */
                          SH_ARGS,                              /* the SH coefficients (sh_in_t) */
                          __constant const float *cam,          /* [CAM_RECORD] */
                          const int width, const int height,
                          const float opacity_override,         /* > 0: every opacity is this */
                          const uint drop_key,                  /* DropGaussian mask key */
                          const uint drop_threshold,            /* keep iff DROP_HASH >= this; 0: keep all */
                          const float drop_scale,               /* kept opacities' factor, 1 / (1 - rate) */
                          __global float *means2d,              /* [N, 2] */
                          __global float *conics,               /* [N, 3] */
                          __global float *depths,               /* [N] */
                          __global int *radii,                  /* [N] 0 = culled */
                          __global int *tile_rect,              /* [N, 4] tx0 ty0 tx1 ty1 */
                          __global float *colors,               /* [N, 3] */
                          __global float *opacities,            /* [N] */
                          __global uint *depth_keys,            /* [N] sort keys */
                          __global uint *gid_vals,              /* [N] sort values = gid */
                          __global uint *ctrl,                  /* the binning's words: ctrl[2] = 0 here */
                          __global float *packed) {             /* [N, 16] the rasterizer's records */
    const sh_in_t sh = SH_IN_OF_ARGS;
#if PROJ_SH_STAGE
    __local float sh_rows[PROJ_WG * SH_LSTRIDE];
    sh_stage_in(n, sh, sh_rows);
    SH_SRC sh_src = sh_rows + get_local_id(0) * SH_LSTRIDE;
#else
    SH_SRC sh_src = sh;
#endif
    LANES(n);
    /* bin_count sums the visible Gaussians into ctrl[2] with atomics (kernels/bin.cl); it is zeroed
       here, in the launch before it in every forward (a fill command would cost one more command
       per forward, and Oclgrind treats filled memory as uninitialised) */
    if (g0 == 0) ctrl[2] = 0u;
#if PROJ_BLOCK_IO
    const int blk = BLOCKS(n);
    raw_t raw_;
    const raw_t *raw = &raw_;
    load_raw(&raw_, blk, g0, gid, means, quats, log_scales, opacity_logits, sh_src);
#endif
    proj_t p;
    vi vis = project_one(gid, means, quats, log_scales, opacity_logits, sh_src, cam, width, height, &p RAW_ARG) & lane_ok;
    if (drop_threshold != 0u) { /* DropGaussian: a dropped Gaussian is culled */
        vu h;
        DROP_HASH(h, AS_U(gid), drop_key);
        vis &= h >= (vu)drop_threshold;
    }
    const vf zero = 0.0f;
    const vf op = opacity_override > 0.0f ? (vf)opacity_override
                                          : (1.0f / (1.0f + exp(-IN_OL))) * drop_scale;
    const vf ln_lo = alpha_rect(&p, op); /* the opacity the rasterizer blends with */
    {
        const vu gv[1] = {AS_U((vi)g0 + VLANES)};
        OUT_ROWS(vu, SCATTER_U, gid_vals, 1, gv);
        const vf m2[2] = {SEL(zero, p.u, vis), SEL(zero, p.v, vis)};
        OUT_ROWS(vf, SCATTER_F, means2d, 2, m2);
        const vf co[3] = {SEL(zero, p.A, vis), SEL(zero, p.B, vis), SEL(zero, p.C, vis)};
        OUT_ROWS(vf, SCATTER_F, conics, 3, co);
        const vf dz[1] = {SEL(zero, p.t[2], vis)};
        OUT_ROWS(vf, SCATTER_F, depths, 1, dz);
        /* radius saturates like the reference's int32 cast */
        const vi rad = SEL(CVT_I(VFMIN(p.radius, 2147483520.0f)), (vi)INT_MAX, p.radius >= 2147483648.0f);
        const vi ra[1] = {SEL((vi)0, rad, vis)};
        OUT_ROWS(vi, SCATTER_I, radii, 1, ra);
        vi tr[4];
        for (int i = 0; i < 4; ++i) tr[i] = SEL((vi)0, CVT_I(p.rect[i]), vis);
        OUT_ROWS(vi, SCATTER_I, tile_rect, 4, tr);
        vf cl[3];
        for (int ch = 0; ch < 3; ++ch) cl[ch] = SEL(zero, VFMAX(p.raw[ch], 0.0f), vis);
        OUT_ROWS(vf, SCATTER_F, colors, 3, cl);
        const vf oo[1] = {SEL(zero, op, vis)};
        OUT_ROWS(vf, SCATTER_F, opacities, 1, oo);
#if PROJ_BLOCK_IO
        if (blk) { /* the rasterizer's records (below, per lane, for the other work-items) */
            const vf f10[10] = {m2[0], m2[1], co[0], co[1], co[2], oo[0], cl[0], cl[1], cl[2], dz[0]};
            raster_prep_lanes(f10, ln_lo, packed + (size_t)PACKED_FLOATS * g0);
        }
#endif
    }
    /* The sort key depends on t_z and the near plane only: t_z's bits wherever t_z > near (finite),
       whatever else culls the Gaussian (frustum, det, radius, tile rect, DropGaussian, opacity), so
       forwards of the same means and camera z row share one depth order (docs/perf_notes.md §9). A
       Gaussian culled otherwise is ranked with an empty tile rect: bin_count gives it no tile.
       t_z > near > 0: the float bits order like the floats. */
    const vi zkey = (p.t[2] > cam[19]) & FINITE(p.t[2]) & lane_ok;
    const vu dk[1] = {SEL((vu)DEPTH_KEY_CULLED, AS_U(p.t[2]), zkey)};
    OUT_ROWS(vu, SCATTER_U, depth_keys, 1, dk);
    /* the rasterizer's records, from the floats just stored (rasterize_prep's inputs and code, common.h):
       a forward on the device launches no rasterize_prep */
#if PROJ_BLOCK_IO
    if (!blk)
#endif
        for (int l = 0; l < nl; ++l) raster_prep_one(g0 + l, means2d, conics, colors, opacities, depths, packed);
}

/* The cotangent rows (v_proj [N, V_PROJ]) of a work-item's lanes for the backward, project_bwd's and
   project_bwd_opacity's (one code, the same bits): vin[i] = entry i of each lane's row / vscale, vscale returned.
   The backward is linear in the cotangents. Huge ones (a colour near FLT_MAX makes its neighbours' cotangents
   overflow) are scaled by an exact power of two, the chain runs on the scaled values and the results are scaled
   back: they may overflow to +-inf, never to inf - inf = NaN. +-inf cotangents saturate at +-FLT_MAX first. NaN
   stays NaN. The rows of culled lanes (vis 0) hold no cotangents (isect_reduce does not write them): such lanes
   use 0 (the per-lane code does not read them; the blocks (blk, PROJ_BLOCK_IO) read them, in bounds, and select 0). */
PROJ_INLINE vf cotangents_in(const int blk, const int g0, const vi gid, const vi vis, __global const float *v_proj,
                             vf *vin) {
    const vf zero = 0.0f;
    const vi vgid = SEL(gid, (vi)(-1), !vis);  /* -1 marks a lane whose row must not be read */
    vf vmax = 0.0f;
#if PROJ_BLOCK_IO
    if (blk) rows_in(v_proj + (size_t)g0 * V_PROJ, V_PROJ, V_PROJ, vin);
#endif
    for (int i = 0; i < V_PROJ; ++i) {
        vf x;
        if (blk) {
            x = SEL(zero, vin[i], vis);
        } else {
#if PROJ_VW > 1
            float tmp[PROJ_VW];
            int idx[PROJ_VW];
            STORE_I(vgid, idx);
            for (int l = 0; l < PROJ_VW; ++l) tmp[l] = idx[l] >= 0 ? v_proj[(size_t)idx[l] * V_PROJ + i] : 0.0f;
            x = VFROM(tmp);
#else
            x = vgid >= 0 ? v_proj[(size_t)vgid * V_PROJ + i] : 0.0f;
#endif
        }
        /* +-inf -> +-FLT_MAX (copysign(FLT_MAX, x) where isinf(x)); vmax = fmax(vmax, |x|) (|x| NaN: vmax) */
        x = SEL(x, AS_F((AS_U(x) & 0x80000000u) | 0x7f7fffffu), (AS_U(x) & 0x7fffffffu) == 0x7f800000u);
        const vf ax = FABS(x);
        vmax = SEL(vmax, ax, ax > vmax);
        vin[i] = x;
    }
    /* vmax in [2^E, 2^(E+1)) (normal when > 2^60): vscale = 2^(E-1) <= 2^126 (finite), built from the
       exponent bits (Oclgrind cannot check a vector frexp); vmax / vscale in [2, 4) */
    const vi ebits = (AS_I(vmax) >> 23) & 0xff;
    const vf vscale = SEL((vf)1.0f, AS_F((ebits - 1) << 23), vmax > PROJ_VSCALE_ABOVE);
    for (int i = 0; i < V_PROJ; ++i) vin[i] /= vscale;
    return vscale;
}

/* d L / d logit (scaled as v_op, the scaled opacity cotangent: cotangents_in) of opacity = sigmoid(logit) *
   drop_scale; 0 under an opacity override (the opacity is then a constant). project_bwd's and
   project_bwd_opacity's (one code, the same bits). */
PROJ_INLINE vf opacity_vjp(const vf v_op, const vf logit, const float opacity_override, const float drop_scale) {
    vf vlogit = 0.0f;
    if (!(opacity_override > 0.0f)) {
        vf op = 1.0f / (1.0f + exp(-logit));
        vlogit = v_op * op * (1.0f - op) * drop_scale; /* opacity = sigmoid(logit) * drop_scale */
    }
    return vlogit;
}

/* Backward projection, one work-item per PROJ_VW Gaussians: raw-field gradients from the
   per-Gaussian cotangents. grad_mask bits: 1 means, 2 quats, 4 log_scales, 8 opacity_logits, 16 sh
   (a field whose bit is clear gets zeros). Culled Gaussians (radii == 0, DropGaussian's dropped ones
   included) get zeros. */
PROJ_INLINE void project_bwd_one(const int n,
                          __global const float *means,          /* [N, 3] */
                          __global const float *quats,          /* [N, 4] */
                          __global const float *log_scales,     /* [N, 3] */
                          __global const float *opacity_logits, /* [N] */
                          SH_SRC sh,                            /* the SH coefficients (staged: this row) */
                          __constant const float *cam,          /* [CAM_RECORD] */
                          const int width, const int height,
                          const float opacity_override,         /* > 0: opacity grad is zero */
                          const float drop_scale,               /* project_fwd's (dropped ones have radii 0) */
                          const int grad_mask,
                          const int grad_acc,                   /* 1: add into the outputs (GRAD_F) */
                          __global const int *radii,            /* [N] from project_fwd */
                          __global const float *v_proj,         /* [N, V_PROJ] (rows of culled gids: values unused) */
                          __global float *v_means,              /* [N, 3] */
                          __global float *v_quats,              /* [N, 4] */
                          __global float *v_log_scales,         /* [N, 3] */
                          __global float *v_opacity_logits,     /* [N] */
                          SH_DST v_sh) {                        /* [N, SH_K, 3] (staged: this row) */
    LANES(n);
    const vf zero = 0.0f;
#if PROJ_BLOCK_IO
    const int blk = BLOCKS(n);
    vi vis = ((blk ? GLD_vi(0, radii + g0) : GATHER_I(radii, gid)) > 0) & lane_ok;
#else
    vi vis = (GATHER_I(radii, gid) > 0) & lane_ok;
#endif
    if (!ANY(vis)) { /* all culled: zeros (the common case for off-screen blocks) */
        const vf z4[4] = {zero, zero, zero, zero};
        GRAD_ROWS(v_means, 3, z4, 1);
        GRAD_ROWS(v_log_scales, 3, z4, 4);
        GRAD_ROWS(v_quats, 4, z4, 2);
        GRAD_ROWS(v_opacity_logits, 1, z4, 8);
        SH_ROWS_ZERO(v_sh);
        return;
    }
#if PROJ_BLOCK_IO
    raw_t raw_;
    const raw_t *raw = &raw_;
    load_raw(&raw_, blk, g0, gid, means, quats, log_scales, opacity_logits, sh);
#endif
    proj_t p;
    vis &= project_one(gid, means, quats, log_scales, opacity_logits, sh, cam, width, height, &p RAW_ARG);

    /* the cotangents, scaled by vscale (cotangents_in) */
#if !PROJ_BLOCK_IO
    const int blk = 0;
#endif
    vf vin[V_PROJ];
    const vf vscale = cotangents_in(blk, g0, gid, vis, v_proj, vin);
    const vf v_u = vin[0], v_v = vin[1], v_A = vin[2], v_B = vin[3], v_C = vin[4];
    const vf v_col[3] = {vin[5], vin[6], vin[7]};
    const vf v_op = vin[8], v_depth = vin[9];

    /* opacity */
    const vf vlogit = opacity_vjp(v_op, IN_OL, opacity_override, drop_scale);
    const vi keep_op = vis & (vi)((grad_mask & 8) ? -1 : 0);
    const vf vo[1] = {SEL(zero, vlogit * vscale, keep_op)};
    GRAD_ROWS(v_opacity_logits, 1, vo, 8);

    /* colour: zero gradient where the 0 clamp is active */
    vf vc[3];
    for (int ch = 0; ch < 3; ++ch) vc[ch] = SEL(zero, v_col[ch], p.raw[ch] >= 0.0f);
#if SH_K > 1
    /* d colour / d dir, first half: v_b[k] = sum_ch sh[k][ch] vc[ch] (the last read of the
       coefficients: staged, v_sh is written over them below) */
    vf vb[SH_K];
    for (int k = 0; k < SH_K; ++k)
        vb[k] = IN_SH(3 * k) * vc[0] + IN_SH(3 * k + 1) * vc[1] + IN_SH(3 * k + 2) * vc[2];
#endif
    vf bas[SH_K];
    sh_basis(p.dir[0], p.dir[1], p.dir[2], bas);
    const vi keep_sh = vis & (vi)((grad_mask & 16) ? -1 : 0);
    {
        vf vsh[SH_K * 3];
        for (int k = 0; k < SH_K; ++k)
            for (int ch = 0; ch < 3; ++ch) vsh[3 * k + ch] = SEL(zero, bas[k] * vc[ch] * vscale, keep_sh);
        SH_ROWS(v_sh, vsh);
    }

    vf vmu[3] = {0.0f, 0.0f, 0.0f};
#if SH_K > 1
    {
        /* second half: the basis Jacobian */
        const vf x = p.dir[0], y = p.dir[1], z = p.dir[2];
        vf gx = -SH_C1 * vb[3], gy = -SH_C1 * vb[1], gz = SH_C1 * vb[2];
#if SH_K > 4
        const vf xx = x * x, yy = y * y, zz = z * z;
        gx += SH_C2_0 * y * vb[4] + SH_C2_2 * (-2.0f * x) * vb[6] + SH_C2_3 * z * vb[7] + SH_C2_4 * 2.0f * x * vb[8];
        gy += SH_C2_0 * x * vb[4] + SH_C2_1 * z * vb[5] + SH_C2_2 * (-2.0f * y) * vb[6] - SH_C2_4 * 2.0f * y * vb[8];
        gz += SH_C2_1 * y * vb[5] + SH_C2_2 * 4.0f * z * vb[6] + SH_C2_3 * x * vb[7];
#endif
#if SH_K > 9
        gx += SH_C3_0 * 6.0f * x * y * vb[9] + SH_C3_1 * y * z * vb[10] + SH_C3_2 * (-2.0f * x * y) * vb[11] +
              SH_C3_3 * (-6.0f * x * z) * vb[12] + SH_C3_4 * (4.0f * zz - 3.0f * xx - yy) * vb[13] +
              SH_C3_5 * 2.0f * x * z * vb[14] + SH_C3_6 * 3.0f * (xx - yy) * vb[15];
        gy += SH_C3_0 * 3.0f * (xx - yy) * vb[9] + SH_C3_1 * x * z * vb[10] +
              SH_C3_2 * (4.0f * zz - xx - 3.0f * yy) * vb[11] + SH_C3_3 * (-6.0f * y * z) * vb[12] +
              SH_C3_4 * (-2.0f * x * y) * vb[13] + SH_C3_5 * (-2.0f * y * z) * vb[14] +
              SH_C3_6 * (-6.0f * x * y) * vb[15];
        gz += SH_C3_1 * x * y * vb[10] + SH_C3_2 * 8.0f * y * z * vb[11] +
              SH_C3_3 * (6.0f * zz - 3.0f * xx - 3.0f * yy) * vb[12] + SH_C3_4 * 8.0f * x * z * vb[13] +
              SH_C3_5 * (xx - yy) * vb[14];
#endif
        /* through dir = d / |d| (no gradient where |d| == 0) */
        const vf dot = x * gx + y * gy + z * gz;
        const vf idn = SEL(zero, 1.0f / p.dnorm, p.dnorm > 0.0f);
        vmu[0] += (gx - x * dot) * idn;
        vmu[1] += (gy - y * dot) * idn;
        vmu[2] += (gz - z * dot) * idn;
    }
#endif

    /* conic -> Sigma2d (a, b, c): conic = inverse of [[a, b], [b, c]] */
    const vf A = p.A, B = p.B, C = p.C;
    const vf va = -(A * A * v_A + A * B * v_B + B * B * v_C);
    const vf vb2 = -(2.0f * A * B * v_A + (A * C + B * B) * v_B + 2.0f * B * C * v_C);
    const vf vc2 = -(B * B * v_A + B * C * v_B + C * C * v_C);
    /* V: gradient w.r.t. the symmetric 2x2 matrix with independent entries (b split in two) */
    const vf V00 = va, V01 = 0.5f * vb2, V11 = vc2;

    /* Sigma2d = J Sc J^T: v_Sc = J^T V J, v_J = 2 V J Sc */
    const vf *J = p.J;
    vf VJ[6]; /* V J, 2x3 */
    for (int j = 0; j < 3; ++j) {
        VJ[j] = V00 * J[j] + V01 * J[3 + j];
        VJ[3 + j] = V01 * J[j] + V11 * J[3 + j];
    }
    vf vJ[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            vJ[3 * i + j] = 2.0f * (VJ[3 * i] * p.Sc[j] + VJ[3 * i + 1] * p.Sc[3 + j] + VJ[3 * i + 2] * p.Sc[6 + j]);
    vf vSc[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) vSc[3 * i + j] = J[i] * VJ[j] + J[3 + i] * VJ[3 + j];

    /* camera-space mean: u, v, depth and J */
    const float fx = cam[12], fy = cam[13];
    const vf tz = p.t[2], rz = 1.0f / tz, rz2 = rz * rz, rz3 = rz2 * rz;
    vf vt[3];
    vt[0] = fx * rz * v_u;
    vt[1] = fy * rz * v_v;
    vt[2] = -fx * p.t[0] * rz2 * v_u - fy * p.t[1] * rz2 * v_v + v_depth;
    /* J00 = fx/tz, J02 = -fx txc/tz^2 (txc = tx unclamped, tz*L clamped) */
    vt[2] += -fx * rz2 * vJ[0] - fy * rz2 * vJ[4];
    vt[0] += SEL(-fx * rz2 * vJ[2], zero, p.clx);
    vt[2] += SEL(2.0f * fx * p.t[0] * rz3 * vJ[2], fx * p.txc * rz3 * vJ[2], p.clx);
    vt[1] += SEL(-fy * rz2 * vJ[5], zero, p.cly);
    vt[2] += SEL(2.0f * fy * p.t[1] * rz3 * vJ[5], fy * p.tyc * rz3 * vJ[5], p.cly);
    /* t = Rc mu + tc */
    for (int j = 0; j < 3; ++j) vmu[j] += cam[j] * vt[0] + cam[3 + j] * vt[1] + cam[6 + j] * vt[2];
    const vi keep_mu = vis & (vi)((grad_mask & 1) ? -1 : 0);
    vf vm[3];
    for (int j = 0; j < 3; ++j) vm[j] = SEL(zero, vmu[j] * vscale, keep_mu);
    GRAD_ROWS(v_means, 3, vm, 1);

    /* Sc = Rc Sigma Rc^T: v_Sigma = Rc^T v_Sc Rc */
    vf T1[9], vS[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) /* T1 = Rc^T v_Sc */
            T1[3 * i + j] = cam[i] * vSc[j] + cam[3 + i] * vSc[3 + j] + cam[6 + i] * vSc[6 + j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) /* vS = T1 Rc */
            vS[3 * i + j] = T1[3 * i] * cam[j] + T1[3 * i + 1] * cam[3 + j] + T1[3 * i + 2] * cam[6 + j];
    /* Sigma = M M^T: v_M = (vS + vS^T) M */
    vf vM[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            vf acc = 0.0f;
            for (int k = 0; k < 3; ++k) acc += (vS[3 * i + k] + vS[3 * k + i]) * p.M[3 * k + j];
            vM[3 * i + j] = acc;
        }
    /* M = R S */
    const vi keep_ls = vis & (vi)((grad_mask & 4) ? -1 : 0);
    vf vls[3];
    for (int j = 0; j < 3; ++j) {
        vf vs = p.R[j] * vM[j] + p.R[3 + j] * vM[3 + j] + p.R[6 + j] * vM[6 + j];
        vls[j] = SEL(zero, vs * p.s[j] * vscale, keep_ls);
    }
    GRAD_ROWS(v_log_scales, 3, vls, 4);
    vf G[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) G[3 * i + j] = vM[3 * i + j] * p.s[j];
    /* R(qn) -> qn */
    const vf w = p.qn[0], x = p.qn[1], y = p.qn[2], z = p.qn[3];
    vf vq[4];
    vq[0] = 2.0f * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]);
    vq[1] = 2.0f * (y * G[1] + z * G[2] + y * G[3] - 2.0f * x * G[4] - w * G[5] + z * G[6] + w * G[7] - 2.0f * x * G[8]);
    vq[2] = 2.0f * (-2.0f * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6] + z * G[7] - 2.0f * y * G[8]);
    vq[3] = 2.0f * (-2.0f * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2.0f * z * G[4] + y * G[5] + x * G[6] + y * G[7]);
    /* qn = q / |q| */
    const vf dq = w * vq[0] + x * vq[1] + y * vq[2] + z * vq[3];
    const vf iq = 1.0f / p.qnorm;
    const vi keep_q = vis & (vi)((grad_mask & 2) ? -1 : 0);
    vf vqo[4];
    for (int i = 0; i < 4; ++i) vqo[i] = SEL(zero, (vq[i] - p.qn[i] * dq) * iq * vscale, keep_q);
    GRAD_ROWS(v_quats, 4, vqo, 2);
}

/* Backward projection kernel: project_bwd_one per work-item (PROJ_SH_STAGE: its SH row in local
   memory, v_sh written over it and copied out per work-group). */
__kernel PROJ_ATTR void project_bwd(const int n,
                          __global const float *means,          /* [N, 3] */
                          __global const float *quats,          /* [N, 4] */
                          __global const float *log_scales,     /* [N, 3] */
                          __global const float *opacity_logits, /* [N] */
                          SH_ARGS,                              /* the SH coefficients (sh_in_t) */
                          __constant const float *cam,          /* [CAM_RECORD] */
                          const int width, const int height,
                          const float opacity_override,         /* > 0: opacity grad is zero */
                          const float drop_scale,               /* project_fwd's (dropped ones have radii 0) */
                          const int grad_mask,
                          const int grad_acc,                   /* 1: add into the outputs (GRAD_F) */
                          __global const int *radii,            /* [N] from project_fwd */
                          __global const float *v_proj,         /* [N, V_PROJ] (rows of culled gids: values unused) */
                          __global float *v_means,              /* [N, 3] */
                          __global float *v_quats,              /* [N, 4] */
                          __global float *v_log_scales,         /* [N, 3] */
                          __global float *v_opacity_logits,     /* [N] */
                          __global float *v_sh,
                          const int stats,                      /* 1: densify_accumulate_one per Gaussian */
                          const dens_real half_w, const dens_real half_h, /* (W/2, H/2), stats only */
                          __global float *accum,                /* [N] += (stats only) */
                          __global int *count,                  /* [N] += (stats only) */
                          __global float *max_radii) {          /* [N] max= (stats only) */
    const sh_in_t sh = SH_IN_OF_ARGS;
#if PROJ_SH_STAGE
    __local float sh_rows[PROJ_WG * SH_LSTRIDE];
    sh_stage_in(n, sh, sh_rows);
    __local float *row = sh_rows + get_local_id(0) * SH_LSTRIDE;
    project_bwd_one(n, means, quats, log_scales, opacity_logits, row, cam, width, height, opacity_override, drop_scale,
                    grad_mask, grad_acc, radii, v_proj, v_means, v_quats, v_log_scales, v_opacity_logits, row);
    sh_stage_out(n, sh_rows, v_sh, grad_acc, grad_mask & 16);
#else
    project_bwd_one(n, means, quats, log_scales, opacity_logits, sh, cam, width, height, opacity_override, drop_scale,
                    grad_mask, grad_acc, radii, v_proj, v_means, v_quats, v_log_scales, v_opacity_logits, v_sh);
#endif
    if (stats) { /* the densification statistics of this work-item's Gaussians (densify.h) */
        const int g0 = (int)get_global_id(0) * PROJ_VW;
        for (int l = 0; l < PROJ_VW; ++l)
            if (g0 + l < n) densify_accumulate_one(g0 + l, radii, v_proj, half_w, half_h, accum, count, max_radii);
    }
}

/* Opacity-only backward (grad_mask 8 alone: the soft depth term's and the DTU background pass's backward,
   backend._project_bwd_device), one work-item per PROJ_VW Gaussians: project_bwd's bytes in every output
   without its projection (project_one) or its chain of the other fields. project_bwd's culling is radii > 0
   and project_one's mask; project_fwd wrote radii > 0 exactly where that mask (the same code on the same
   inputs, which the caller keeps from the forward to its backward) and DropGaussian's mask kept the
   Gaussian (a visible radius is at least 1), so radii > 0 alone decides here. The opacity's gradient is
   the same code as project_bwd's (cotangents_in, which reads every entry of a row for its scale, and
   opacity_vjp), or where no row of a full work-item is scaled, the unscaled v_op it would give (below).
   grad_acc 0: v_opacity_logits written, every other field +0.0 (project_bwd's zeros for the fields
   outside grad_mask); 1: v_opacity_logits added into (GRAD_F: out + 0.0 on culled rows too), the other
   fields untouched. */
__kernel void project_bwd_opacity(const int n,
                                  __global const float *opacity_logits, /* [N] */
                                  const float opacity_override,         /* > 0: opacity grad is zero */
                                  const float drop_scale,               /* project_fwd's (dropped ones have radii 0) */
                                  const int grad_acc,                   /* 1: add into v_opacity_logits (GRAD_F) */
                                  __global const int *radii,            /* [N] from project_fwd */
                                  __global const float *v_proj,         /* [N, V_PROJ] (rows of culled gids: unused) */
                                  __global float *v_means,              /* [N, 3] (grad_acc 0: zeros) */
                                  __global float *v_quats,              /* [N, 4] (grad_acc 0: zeros) */
                                  __global float *v_log_scales,         /* [N, 3] (grad_acc 0: zeros) */
                                  __global float *v_opacity_logits,     /* [N] */
                                  __global float *v_sh) {               /* [N, SH_K, 3] (grad_acc 0: zeros) */
    const int grad_mask = 8; /* GRAD_ROWS: the opacity's field alone is added into with grad_acc 1 */
    LANES(n);
#if PROJ_BLOCK_IO
    const int blk = BLOCKS(n);
    const vi vis = ((blk ? GLD_vi(0, radii + g0) : GATHER_I(radii, gid)) > 0) & lane_ok;
    const vf logit = blk ? GLD_vf(0, opacity_logits + g0) : GATHER(opacity_logits, gid);
#else
    const int blk = 0;
    const vi vis = (GATHER_I(radii, gid) > 0) & lane_ok;
    const vf logit = GATHER(opacity_logits, gid);
#endif
    vf v_op, vscale;
    int small = 0;
#if PROJ_VW > 1
    /* A full work-item's rows are PROJ_VW * V_PROJ consecutive floats: read as V_PROJ vectors (no transpose), they
       tell whether every row's max |entry| is at most PROJ_VSCALE_ABOVE, where cotangents_in's vscale is 1 on
       every lane and its saturation and division leave v_op as it is (no inf in it): then only v_op is taken,
       at a third of cotangents_in's time. |x| orders as its bits (x not NaN); inf counts as big; a NaN is ignored,
       as vmax ignores it. Rows of culled lanes count too (stale values): a big one only sends the work-item to
       cotangents_in, the same bits. */
    if (nl == PROJ_VW) {
        __global const float *rows = v_proj + (size_t)g0 * V_PROJ;
        vi big = 0;
        for (int k = 0; k < V_PROJ; ++k) {
            const vu a = AS_U(VLOAD_F(k, rows)) & 0x7fffffffu;
            big |= (a > as_uint(PROJ_VSCALE_ABOVE)) & (a <= 0x7f800000u);
        }
        small = !ANY(big);
        if (small) {
            float t[PROJ_VW];
            for (int l = 0; l < PROJ_VW; ++l) t[l] = rows[V_PROJ * l + 8];
            v_op = VFROM(t); /* culled lanes: stale values, masked below */
            vscale = 1.0f;
        }
    }
#endif
    if (!small) {
        vf vin[V_PROJ];
        vscale = cotangents_in(blk, g0, gid, vis, v_proj, vin);
        v_op = vin[8];
    }
    const vf vo[1] = {SEL((vf)0.0f, opacity_vjp(v_op, logit, opacity_override, drop_scale) * vscale, vis)};
    GRAD_ROWS(v_opacity_logits, 1, vo, 8);
    if (!grad_acc) { /* the work-item's rows of the other fields, contiguous in each: +0.0 */
        const size_t r0 = (size_t)g0, r1 = (size_t)(g0 + nl);
        for (size_t i = 3 * r0; i < 3 * r1; ++i) v_means[i] = 0.0f;
        for (size_t i = 4 * r0; i < 4 * r1; ++i) v_quats[i] = 0.0f;
        for (size_t i = 3 * r0; i < 3 * r1; ++i) v_log_scales[i] = 0.0f;
        for (size_t i = 3 * SH_K * r0; i < 3 * SH_K * r1; ++i) v_sh[i] = 0.0f;
    }
}
