/* rasterize.cl: tile rasterizer, forward and backward, importance records, segmented reduce.
 *
 * Must match reings.backends.reference.rasterize_fwd / rasterize_bwd (issue #2 §3):
 * per pixel, front to back along its tile's list (sorted by (tile, depth, gid)):
 *   d = (u, v) - pixel centre, power = -0.5 (A dx^2 + C dy^2) - B dx dy; skip if power > 0;
 *   alpha = min(ALPHA_MAX, o exp(power)); skip if alpha < ALPHA_MIN;
 *   stop *before* the Gaussian if T (1 - alpha) < T_MIN;
 *   colour += c alpha T, depth += z alpha T, T *= 1 - alpha;  rgb = colour + T bg, alpha = 1 - T.
 * last = 1 + position (in the tile's list) of the pixel's last blended Gaussian, 0 for none.
 *
 * Kernels
 *   rasterize_prep  per gid: packs (u, v, A, B, C, o, r, g, b, z) plus the pixel box outside of
 *                   which alpha < ALPHA_MIN (opacity-aware, conservative by 1% + 0.5 px) into one
 *                   float16 record, so a (tile, Gaussian) pair costs one 64-byte gather.  The box
 *                   only skips pairs the per-pixel test would skip anyway (same function). Its code
 *                   is common.h's raster_prep_one, which project_fwd also calls: a forward on the
 *                   device writes the records there, and rasterize_prep runs only for an uploaded
 *                   projection (the stage API).
 *   rasterize_fwd   images; with -D RASTER_IMPORTANCE=1 also imp_emit[emit] = sum over the tile's
 *                   pixels of alpha T (every emit slot of the tile is written, 0 if unused).
 *   rasterize_bwd   per-intersection gradient records v_emit[emit, V_RECORD] =
 *                   (v_u, v_v, v_A, v_B, v_C, v_r, v_g, v_b, v_opacity, v_z), each (tile, Gaussian)
 *                   pair summed over the tile's pixels: no per-pixel atomics, deterministic.
 *                   Front-to-back replay (Brush): T is never recovered by division; the colour
 *                   behind a Gaussian comes from the forward output minus what was blended so far,
 *                   folded with the cotangents into one scalar R per pixel.
 *   isect_reduce    out[gid_from_rank[r], :] (+)= sum of records[offset_from_rank[r] ..
 *                   offset_from_rank[r+1], :], records of width `width` (10: gradients, 1: importance),
 *                   for r < V: the scalar n_rank, or the device's ctrl[0] (sync-free binning, counts /
 *                   count_at, common.h launch_count);
 *                   a sum that overflows is redone scaled (see Overflow): +-inf or finite, never NaN.
 *                   CPU schedule: a work-item walks its rank's records; GPU schedule: RED_LANES
 *                   work-items per rank stage them in local memory, lane f adds field f in record
 *                   order (the same bits as the CPU schedule's walk).
 *
 * Defines (defaults): REINGS_CPU_SCHEDULE (0), REINGS_NV_PTX (0), REINGS_CLANG_BUILTINS (0) from
 *   quirks.build_defines;
 *   RASTER_ROW_IO (1; CPU schedule at 4-pixel-wide blocks): a block wholly inside the image reads (backward) and
 *   writes (forward) its pixels a row of 4 at a time, each lane's values by the scalar loop's expressions (the
 *   same bits; docs/perf_notes.md §30);
 *   RASTER_PREFETCH (4 where REINGS_CLANG_BUILTINS and the compiler has __builtin_prefetch, else 0; CPU
 *   schedule): the forward and backward prefetch the record this many list positions ahead (the loads of
 *   random records were ~5-8 % of their time; docs/perf_notes.md §30; no value changes);
 *   RASTER_EXP_INLINE (2 where REINGS_CLANG_BUILTINS on an x86-64 with FMA, else 0; CPU schedule): exp written
 *   out as PoCL 3.0's own vector exp's operations (1: over its whole range; 2: the same bits on [-87, 88], the
 *   rasterizer's lanes; no call either way); RASTER_PLAIN_IO (REINGS_CLANG_BUILTINS; CPU schedule):
 *   the tiles' pixel loads and stores as plain operators instead of vload / vstore calls (the same bytes); both
 *   below, docs/perf_notes.md §40;
 *   RASTER_IMPORTANCE (0); RASTER_VEC (8 here; CPU pixel lanes, 8 = AVX2, 16 = AVX-512: the host always
 *   passes it, $REINGS_RASTER_VEC, else 16 where the device's native float vector is 16 wide, else 8:
 *   reings.backends.opencl.rasterize.raster_vec);
 *   RASTER_BLOCK_H (RASTER_VEC / 4, CPU schedule): a pixel vector is RASTER_BLOCK_H rows of
 *   RASTER_VEC / RASTER_BLOCK_H pixels (4 x 2 or 4 x 4: fewer vectors per Gaussian than one row of 8 or
 *   16, docs/perf_notes.md §27); every shape gives each pixel the same values (the same bytes of the
 *   forward's images), only the order of a tile's per-Gaussian sums differs;
 *   FWD_BATCH (256) / BWD_BATCH (64): Gaussians staged in local memory per batch (GPU schedule; the batch
 *   only partitions a tile's list: any BWD_BATCH gives the same records, docs/perf_notes.md §28);
 *   REDUCE_CHUNK (1; the host passes 16): isect_reduce's ranks per work-item on the CPU schedule;
 *   RED_LANES (16) / RED_WG (256) / RED_STAGE (320): isect_reduce's GPU schedule, work-items per rank,
 *   per work-group, and floats staged per rank and round (the host passes the first two);
 *   BWD_PIX (1): rasterize_bwd's GPU schedule, pixels per work-item (1, 2 or 4; work-groups of
 *   256 / BWD_PIX): each work-item adds its pixels' values before the per-Gaussian group sum, so 2
 *   halves the warp sums (docs/perf_notes.md §28); the host passes $REINGS_BWD_PIX, else 1;
 *   RASTER_BWD_OPACITY (0): 1 builds rasterize_bwd for a backward whose only wanted gradient is the
 *   opacities' (the soft depth term's and the DTU background pass's backward, grad_fields =
 *   opacity_logits): the same d out / d alpha recursion, but only record field 8 (d/d opacity) is
 *   summed and written, the other fields are written as 0. Field 8 keeps its bits: the per-field sums
 *   are independent (the same lanes, the same tree or warp shuffles, the same order).
 *   (docs/perf_notes.md §11)
 *   RASTER_BWD_DEPTH_O (0): 1 builds rasterize_bwd with a second depth cotangent v_depth_o whose
 *   gradient goes to the opacities alone (the shared soft depth term, taken on the photometric
 *   render): besides the records of (v_rgb, v_depth, v_alpha) in v_emit, the records of v_depth_o
 *   alone go to v_emit_o, laid out as a RASTER_BWD_OPACITY backward writes them (field 8, the other
 *   fields 0) and with its bits: per pixel the same T, the same expressions on a cotangent of
 *   its own (R_o = v_depth_o * out_depth, c_o = v_depth_o * z), summed over the tile the same way.
 *   (Finite colours assumed: the separate pass multiplies its zero colour cotangents by them.) The
 *   overflow rerun of a tile scales by the bounds of all four cotangents. (docs/perf_notes.md §13)
 *   RASTER_ALPHA_CUT (1, CPU schedule): skip a pixel vector's exp and blend where every lane's power
 *   is below the record's power cut (ALPHA_CUT_LN, common.h: alpha < ALPHA_MIN there for certain, so those lanes
 *   fail the pixel test anyway) or, in the forward, has already stopped (T < 0: fails it too); 0
 *   evaluates every vector of the box. The same bits either way
 *   (tests/test_rasterize.py; docs/perf_notes.md §22).
 *   RASTER_CUT_MASK (1, CPU schedule): a Gaussian's box is walked twice: first its vectors' powers and
 *   skip tests, with no branch per vector (the tests' outcomes set bits of a vset; a branch on each was
 *   often mispredicted), then the vectors whose bit is set, in the same order (low_bit, common.h). A vector
 *   skipped either way has no ok lane, so the same bits (docs/perf_notes.md §31); 0 branches per vector.
 *   RASTER_HITS (RASTER_CUT_MASK, CPU schedule): rasterize_fwd writes each visited pair's set of vectors past its
 *   tests to hits[i] (0 where the box misses the tile; pairs after the tile stopped are not written and never
 *   read), and rasterize_bwd with use_hits = 1 tests that set's vectors instead of the box's: the host passes
 *   use_hits only for the backward of the last forward with the same bins, size and records
 *   (reings.backends.opencl.rasterize.Rasterizer.bwd). The set holds every vector the backward's own tests pass
 *   (a lane before its pixel's last was active at that Gaussian in the forward), so testing it gives exactly the
 *   backward's set: the same bits, non-finite cotangents included; the box's other vectors never walked (0.90-0.94
 *   of the backward's time against RASTER_CENTRES alone, docs/perf_notes.md §33).
 *   RASTER_CENTRES (1, CPU schedule): the pixel centres of the tile's block columns and rows in a table made once
 *   per tile (CENTRES: the same expressions, the same bits) instead of at each use (0.93-0.96 of the forward's and
 *   0.90-0.95 of the backward's time, docs/perf_notes.md §33).
 * Schedules (same algorithm, same results up to float rounding of sums):
 *   CPU: one work-item per tile (local size 1), no barriers; the tile's 256 pixels are
 *        RASTER_VEC-wide vectors (blocks of RASTER_BLOCK_H pixel rows) in private arrays; Gaussians
 *        are the outer loop (uniform scalar loads), each visits only the block rows and columns of
 *        its box; per-pixel and whole-tile
 *        early exit; per-(tile, Gaussian) sums stay in registers and are written once.
 *   GPU: one 256-work-item group per tile, a work-item per pixel (rasterize_bwd: BWD_PIX pixels per
 *        work-item, groups of 256 / BWD_PIX), Gaussians staged in local memory
 *        by batches, whole-tile early exit; per-Gaussian work-group sums by warp shuffles
 *        (shfl.sync.bfly, REINGS_NV_PTX) + a local combine across warps, else a local tree.
 * Overflow (rasterize_bwd, isect_reduce): finite inputs can still overflow float32 in the backward.
 *   A colour near FLT_MAX makes v.c, R and d out/d alpha overflow, and one Gaussian's per-pixel terms
 *   reach +inf and -inf: inf - inf and 0 * inf used to give NaN. The backward is linear in the
 *   cotangents and, on the d/d alpha path, in the colours, depths and forward outputs. So a tile runs
 *   once unscaled (the common case: results unchanged, the scales are literal 1s that fold away);
 *   only if one of its records is not finite does it run again with the cotangents scaled by sv and
 *   the colours, depths and outputs by sk, exact powers of two that bring both below 2^29. Then every
 *   intermediate stays below ~2^122 (boxes of at most 1e7 px, conics of project_fwd: at most
 *   1/EPS2D), and the records are scaled back: +-inf where the gradient itself exceeds FLT_MAX,
 *   never NaN. +-inf cotangents saturate at +-FLT_MAX; NaN inputs stay NaN. isect_reduce re-sums a
 *   row whose plain sum is not finite the same way (terms saturated, one power-of-two scale).
 *   Accuracy there is float32's: a Gaussian behind a huge colour gets its R by cancellation of huge
 *   values (finite, error ~1e-7 of that colour times its cotangent).
 * Not handled: non-finite inputs are culled by the projection (the box test still rejects NaN
 * opacity/means); tile lists must be sorted front to back.
 */
#include "common.h"

/* isfinite(x) as plain integer operations (PoCL 3.0 makes isfinite a call; see the CPU schedule) */
#define FINITE(x) ((as_uint(x) & 0x7f800000u) != 0x7f800000u)

#ifndef RASTER_IMPORTANCE
#define RASTER_IMPORTANCE 0
#endif
#ifndef RASTER_ALPHA_CUT
#define RASTER_ALPHA_CUT 1
#endif
#ifndef RASTER_VEC
#define RASTER_VEC 8
#endif
#ifndef RASTER_ROW_IO /* CPU schedule: a pixel block inside the image read / written a row of 4 pixels at a time */
#define RASTER_ROW_IO 1
#endif
#ifndef RASTER_CUT_MASK /* CPU schedule: the cut tests of a Gaussian's box first, without branches, then its vectors past them */
#define RASTER_CUT_MASK 1
#endif
#ifndef RASTER_HITS /* CPU schedule: the forward keeps each pair's set of vectors past its cut tests for the backward */
#define RASTER_HITS RASTER_CUT_MASK
#endif
#if RASTER_HITS && !RASTER_CUT_MASK
#error "RASTER_HITS needs RASTER_CUT_MASK (the sets are its tests' outcomes)"
#endif
#ifndef RASTER_PREFETCH /* CPU schedule: prefetch the record this many list positions ahead (0: none) */
#define RASTER_PREFETCH (REINGS_HAS_PREFETCH ? 4 : 0)
#endif
#ifndef RASTER_BLOCK_H
#define RASTER_BLOCK_H (RASTER_VEC / 4)
#endif
#ifndef FWD_BATCH
#define FWD_BATCH 256
#endif
#ifndef BWD_BATCH
#define BWD_BATCH 64
#endif
#ifndef RASTER_BWD_OPACITY
#define RASTER_BWD_OPACITY 0
#endif
#ifndef RASTER_BWD_DEPTH_O
#define RASTER_BWD_DEPTH_O 0
#endif
#ifndef RASTER_BWD_TRANSPOSE
#define RASTER_BWD_TRANSPOSE 1 /* NVIDIA: the backward's per-field warp sums in one transposed sum */
#endif
#ifndef REDUCE_CHUNK
#define REDUCE_CHUNK 1 /* isect_reduce, CPU schedule: ranks per work-item (Rasterizer.reduce_chunk) */
#endif
#if REDUCE_CHUNK < 1
#error "REDUCE_CHUNK must be at least 1"
#endif
#if V_RECORD + 1 > 16
#error "the transposed warp sum holds at most 16 fields"
#endif
#if RASTER_BWD_OPACITY && RASTER_BWD_DEPTH_O
#error "RASTER_BWD_OPACITY and RASTER_BWD_DEPTH_O exclude each other"
#endif
#if RASTER_BWD_OPACITY
#define BWD_FIELDS 1 /* the GPU schedule's per-Gaussian sums: field 8 only */
#elif RASTER_BWD_DEPTH_O
#define BWD_FIELDS (V_RECORD + 1) /* + v_depth_o's d/d opacity, written to v_emit_o */
#else
#define BWD_FIELDS V_RECORD
#endif

/* ------------------------------------------------------------------------------------------ */
/* rasterize_prep                                                                              */

__kernel void rasterize_prep(__global const float *means2d,   // [N, 2]
                             __global const float *conics,    // [N, 3]
                             __global const float *colors,    // [N, 3]
                             __global const float *opacities, // [N]
                             __global const float *depths,    // [N]
                             __global float *packed,          // [N, 16] out
                             const int n) {
    const int g = get_global_id(0);
    if (g >= n) return;
    raster_prep_one(g, means2d, conics, colors, opacities, depths, packed);
}

/* ------------------------------------------------------------------------------------------ */
/* overflow helpers (rasterize_bwd pass 1, isect_reduce)                                       */

/* +-inf -> +-FLT_MAX; finite values and NaN unchanged */
inline float sat_inf(float x) { return isinf(x) ? copysign(FLT_MAX, x) : x; }

/* x * s for s an exact power of two (rasterize_bwd's scales). s != 1 only in a rescaled pass, whose
 * bounds put every +-inf input at a scale below 1: there +-inf saturates at +-FLT_MAX first. With a
 * literal s = 1 (the first pass) this folds to plain x. */
inline float scaled(float x, float s) { return s == 1.0f ? x : sat_inf(x) * s; }

/* m in [0, FLT_MAX], not NaN, with exponent E (m in [2^E, 2^(E+1))): 2^(target - E) when E > target,
 * else 1. An exact power of two that brings m below 2^(target + 1); its reciprocal is exact too.
 * Built from the exponent bits (no frexp: Oclgrind). */
inline float pow2_scale_down(float m, int target) {
    const int e = ((as_int(m) >> 23) & 0xff) - 127;
    return e > target ? as_float((target - e + 127) << 23) : 1.0f;
}

/* ------------------------------------------------------------------------------------------ */
/* isect_reduce: segmented sum of per-emit records into per-Gaussian rows                      */

/* The overflow fallback of one field (rare): the sum overflowed (+inf and -inf records, or partial
 * sums, would give NaN). Again with +-inf saturated to +-FLT_MAX and every term scaled by one exact
 * power of two (at most 2^101 each): the result overflows to +-inf, never to NaN; NaN stays NaN. */
inline float reduce_rescaled(__global const float *records, const int a, const int b, const int width, const int f,
                             const float s0) {
    float m = fabs(sat_inf(s0));
    for (int e = a; e < b; ++e) m = fmax(m, fabs(sat_inf(records[(size_t)e * width + f]))); /* skips NaN */
    const float sc = pow2_scale_down(m, 100);
    float t = sat_inf(s0) * sc;
    for (int e = a; e < b; ++e) t += sat_inf(records[(size_t)e * width + f]) * sc;
    return t * (1.0f / sc);
}

/* isect_reduce's arguments (both schedules): records [K_emit, width], offset_from_rank [V + 1], gid_from_rank
 * [V], out [N, width]; V = counts[count_at] when count_at >= 0, else n_rank (the launch bound; common.h) */
#define ISECT_REDUCE_PARAMS                                                                                \
    __global const float *records, __global const int *offset_from_rank, __global const int *gid_from_rank, \
        __global float *out, const int n_rank, const int width, const int accumulate,                      \
        __global const uint *counts, const int count_at

#if REINGS_CPU_SCHEDULE
#if V_RECORD != 10
#error "isect_reduce's REDUCE_CHUNK form sums a gradient record as a float8 and a float2: V_RECORD must be 10"
#endif
/* CPU schedule, REDUCE_CHUNK ranks per work-item (the host launches ceil(V / REDUCE_CHUNK); Rasterizer.reduce_chunk):
 * each field's sum is s0 + records[a] + records[a + 1] + ... in that order, a gradient record's fields as a float8 and
 * a float2 of running sums (lane by lane: the per-field loop's adds, the same bits). At 16 ranks 0.46-0.50x of the time
 * of one rank per work-item with the fields in scalars (its form until session 46; fern's fine and final states, 2 Xeon
 * cores, docs/perf_notes.md §43). With REINGS_CLANG_BUILTINS the loads and
 * stores are operators on 4-byte-aligned vector types (PoCL calls vload8), elsewhere vload8 / vstore8. */
#if REINGS_CLANG_BUILTINS
typedef float8 __attribute__((aligned(4), may_alias)) f8u_red;
typedef float2 __attribute__((aligned(4), may_alias)) f2u_red;
#define RLOAD8(p) (*(__global const f8u_red *)(p))
#define RLOAD2(p) (*(__global const f2u_red *)(p))
#define RSTORE8(v, p) (*(__global f8u_red *)(p) = (v))
#define RSTORE2(v, p) (*(__global f2u_red *)(p) = (v))
#else
#define RLOAD8(p) vload8(0, p)
#define RLOAD2(p) vload2(0, p)
#define RSTORE8(v, p) vstore8(v, 0, p)
#define RSTORE2(v, p) vstore2(v, 0, p)
#endif
__kernel void isect_reduce(ISECT_REDUCE_PARAMS) {
    const int v = (int)launch_count((uint)n_rank, counts, count_at);
    const int r0 = get_global_id(0) * REDUCE_CHUNK, r1 = min(r0 + REDUCE_CHUNK, v);
    for (int r = r0; r < r1; ++r) {
        const int a = offset_from_rank[r], b = offset_from_rank[r + 1];
        const int gid = gid_from_rank[r];
        if (width == V_RECORD) {
            __global float *o = out + (size_t)gid * V_RECORD;
            float8 s8 = accumulate ? RLOAD8(o) : (float8)(0.0f);
            float2 s2 = accumulate ? RLOAD2(o + 8) : (float2)(0.0f);
            for (int e = a; e < b; ++e) {
                __global const float *rec = records + (size_t)e * V_RECORD;
                s8 += RLOAD8(rec);
                s2 += RLOAD2(rec + 8);
            }
            const int8 bad8 = (as_int8(s8) & 0x7f800000) == 0x7f800000; /* !FINITE per lane */
            const int2 bad2 = (as_int2(s2) & 0x7f800000) == 0x7f800000;
            if (any8(bad8) || (bad2.x | bad2.y) < 0) { /* rare: the fields that overflowed, rescaled */
                float t[V_RECORD] = {s8.s0, s8.s1, s8.s2, s8.s3, s8.s4, s8.s5, s8.s6, s8.s7, s2.s0, s2.s1};
                for (int f = 0; f < V_RECORD; ++f)
                    if (!FINITE(t[f])) t[f] = reduce_rescaled(records, a, b, V_RECORD, f, accumulate ? o[f] : 0.0f);
                s8 = (float8)(t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7]);
                s2 = (float2)(t[8], t[9]);
            }
            RSTORE8(s8, o);
            RSTORE2(s2, o + 8);
            continue;
        }
        for (int f = 0; f < width; ++f) { /* other widths (the importance records): field by field */
            const float s0 = accumulate ? out[gid * width + f] : 0.0f;
            float s = s0;
            for (int e = a; e < b; ++e) s += records[e * width + f];
            if (!FINITE(s)) s = reduce_rescaled(records, a, b, width, f, s0);
            out[gid * width + f] = s;
        }
    }
}
#else
/* GPU schedule: RED_LANES work-items per rank, RED_WG / RED_LANES ranks per work-group. A rank's
 * records come to local memory in rounds of RED_STAGE floats, loaded by its lanes together
 * (consecutive lanes, consecutive floats); then lane f < width adds field f of the round's records
 * in record order. So every field is s0 + records[a] + records[a + 1] + ... in that order, the CPU
 * schedule's bits, while a long segment's loads (a Gaussian over hundreds of tiles) are issued
 * RED_LANES at a time instead of one work-item's chain, and a short one's are coalesced.
 * width <= RED_LANES (the host checks). The group's ranks all take as many rounds as its longest
 * (barriers); a rank >= V takes none of its own. (docs/perf_notes.md §28: 16 lanes against 32 and
 * against a work-item per rank over the group's staged block, on an H100.) */
#ifndef RED_LANES
#define RED_LANES 16
#endif
#ifndef RED_WG
#define RED_WG 256
#endif
#ifndef RED_STAGE
#define RED_STAGE 320 /* floats per rank and round: 32 gradient records, 320 importance records */
#endif
#if V_RECORD > RED_LANES || RED_WG % RED_LANES || RED_STAGE < RED_LANES
#error "isect_reduce: RED_LANES must hold a gradient record's fields and divide RED_WG"
#endif
#define RED_RANKS (RED_WG / RED_LANES)
__kernel __attribute__((reqd_work_group_size(RED_WG, 1, 1))) void
isect_reduce(ISECT_REDUCE_PARAMS) {
    __local float stage[RED_RANKS * RED_STAGE];
    __local int rounds;
    const int lid = get_local_id(0);
    const int sub = lid / RED_LANES, lane = lid - sub * RED_LANES;
    const int r = get_group_id(0) * RED_RANKS + sub;
    const int live = r < (int)launch_count((uint)n_rank, counts, count_at);
    const int per = RED_STAGE / width; /* records per round */
    int a = 0, b = 0, gid = 0;
    if (live) {
        a = offset_from_rank[r];
        b = offset_from_rank[r + 1];
        gid = gid_from_rank[r];
    }
    if (lid == 0) rounds = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (live && lane == 0 && b > a) atomic_max(&rounds, (b - a + per - 1) / per);
    barrier(CLK_LOCAL_MEM_FENCE);
    const int n_rounds = rounds;
    const int mine = live && lane < width;
    const float s0 = mine && accumulate ? out[gid * width + lane] : 0.0f;
    float s = s0;
    __local float *st = stage + sub * RED_STAGE;
    for (int c = 0; c < n_rounds; ++c) {
        const int e0 = a + c * per;
        const int ne = live ? clamp(b - e0, 0, per) : 0; /* this rank's records in this round */
        barrier(CLK_LOCAL_MEM_FENCE);                   /* the previous round's adds are done */
        for (int q = lane; q < ne * width; q += RED_LANES) st[q] = records[(size_t)e0 * width + q];
        barrier(CLK_LOCAL_MEM_FENCE);
        if (mine)
            for (int e = 0; e < ne; ++e) s += st[e * width + lane];
    }
    if (mine) {
        if (!FINITE(s)) s = reduce_rescaled(records, a, b, width, lane, s0);
        out[gid * width + lane] = s;
    }
}
#endif

#if REINGS_CPU_SCHEDULE
/* ========================================================================================== */
/* CPU schedule                                                                                */

/* PoCL 3.0 (pocl-binary-distribution) calls its builtins rather than inlining them: in the pixel loops
 * every select / any / fmin / min / max was a call, around which every live vector register is spilled
 * (objdump of PoCL's kernel cache; docs/perf_notes.md §17). The CPU schedule writes them with plain
 * operators instead, the same value for every input: SEL(a, b, c) and any8 (common.h) are select and any,
 * VMIN(x, a) is fmin(a, x) (a NaN x gives a), FINITE (above) is isfinite; VEXP (below) is exp. */
#define VMIN(x, a) ((x) < (a) ? (x) : (a))
#define IMIN(a, b) ((a) < (b) ? (a) : (b))
#define IMAX(a, b) ((a) > (b) ? (a) : (b))

#if RASTER_VEC == 8
typedef float8 vf;
typedef int8 vi;
#define ILANES ((vi)(0, 1, 2, 3, 4, 5, 6, 7))
#define VLOAD vload8
#define VCVT convert_float8
#define VSTORE vstore8
inline float hsum(vf x) {
    float4 a = x.lo + x.hi;
    float2 b = a.lo + a.hi;
    return b.x + b.y;
}
inline int hcount(vi m) {
    int4 a = (m & 1).lo + (m & 1).hi;
    int2 b = a.lo + a.hi;
    return b.x + b.y;
}
inline int hmax(vi x) {
    int4 a = IMAX(x.lo, x.hi);
    int2 b = IMAX(a.lo, a.hi);
    return IMAX(b.x, b.y);
}
inline int vany(vi m) { return any8(m); } /* any(m) */
#elif RASTER_VEC == 16
typedef float16 vf;
typedef int16 vi;
#define ILANES ((vi)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define VLOAD vload16
#define VCVT convert_float16
#define VSTORE vstore16
inline float hsum(vf x) {
    float8 a8 = x.lo + x.hi;
    float4 a = a8.lo + a8.hi;
    float2 b = a.lo + a.hi;
    return b.x + b.y;
}
inline int hcount(vi m) {
    int8 a8 = (m & 1).lo + (m & 1).hi;
    int4 a = a8.lo + a8.hi;
    int2 b = a.lo + a.hi;
    return b.x + b.y;
}
inline int hmax(vi x) {
    int8 a8 = IMAX(x.lo, x.hi);
    int4 a = IMAX(a8.lo, a8.hi);
    int2 b = IMAX(a.lo, a.hi);
    return IMAX(b.x, b.y);
}
inline int vany(vi m) { return any16(m); } /* any(m) */
#else
#error "RASTER_VEC must be 8 or 16"
#endif

/* RASTER_PLAIN_IO (CPU schedule; default REINGS_CLANG_BUILTINS): the tiles' pixel loads and stores (the
 * forward's outputs, the backward's cotangents and forward outputs, the private rows between them) as plain
 * operators on 4-byte-aligned, may_alias vector types instead of vload / vstore, which PoCL 3.0 calls (§17 of
 * docs/perf_notes.md: a call spills every live vector register): the same bytes moved (on / off byte for byte:
 * tests/test_rasterize.py::test_cpu_io_and_builtins_keep_the_bits). G: __global, P: private; 4: a float4 at
 * p + 4 o, V: a pixel vector at p; I: the int forms. */
#ifndef RASTER_PLAIN_IO
#define RASTER_PLAIN_IO REINGS_CLANG_BUILTINS
#endif
#if RASTER_PLAIN_IO
typedef float4 __attribute__((aligned(4), may_alias)) f4u;
typedef int4 __attribute__((aligned(4), may_alias)) i4u;
typedef vf __attribute__((aligned(4), may_alias)) vfu;
typedef vi __attribute__((aligned(4), may_alias)) viu;
#define GLOAD4(o, p) (((__global const f4u *)(p))[o])
#define GLOAD4I(o, p) (((__global const i4u *)(p))[o])
#define GSTORE4(v, o, p) (((__global f4u *)(p))[o] = (v))
#define GSTORE4I(v, o, p) (((__global i4u *)(p))[o] = (v))
#define PLOAD4(o, p) (((const f4u *)(p))[o])
#define PLOAD4I(o, p) (((const i4u *)(p))[o])
#define PSTORE4(v, o, p) (((f4u *)(p))[o] = (v))
#define PSTORE4I(v, o, p) (((i4u *)(p))[o] = (v))
#define PLOADV(p) (*(const vfu *)(p))
#define PLOADVI(p) (*(const viu *)(p))
#define PSTOREV(v, p) (*(vfu *)(p) = (v))
#define PSTOREVI(v, p) (*(viu *)(p) = (v))
#else
#define GLOAD4(o, p) vload4(o, p)
#define GLOAD4I(o, p) vload4(o, p)
#define GSTORE4(v, o, p) vstore4(v, o, p)
#define GSTORE4I(v, o, p) vstore4(v, o, p)
#define PLOAD4(o, p) vload4(o, p)
#define PLOAD4I(o, p) vload4(o, p)
#define PSTORE4(v, o, p) vstore4(v, o, p)
#define PSTORE4I(v, o, p) vstore4(v, o, p)
#define PLOADV(p) VLOAD(0, p)
#define PLOADVI(p) VLOAD(0, p)
#define PSTOREV(v, p) VSTORE(v, 0, p)
#define PSTOREVI(v, p) VSTORE(v, 0, p)
#endif

/* RASTER_EXP_INLINE (CPU schedule; default 2 where REINGS_CLANG_BUILTINS and clang targets an x86-64 with FMA,
 * __FMA__, else 0): at 1 VEXP(x) is exp_inline(x), exp(x) written out in operators, the operations of PoCL 3.0's own vector exp on x86-64
 * with FMA (Sleef's expf_u10: n = rint(x / ln 2) by a product and a round to nearest even, the reduction
 * s = x - n ln 2 in two fused steps (ln 2 split 0.693145751953125 + 1.428606765330187e-06), a degree-5 polynomial
 * by Horner's fused steps, u = s^2 P(s) + s, then 1 + u, times 2^(n >> 1) and 2^(n - (n >> 1)) built in the
 * exponent bits; 0 below -104, inf above 100), in the same order, so the same bits for every input (checked
 * against the build's exp by tests/test_rasterize.py::test_inline_exp_is_the_library_exp on every float of a dense
 * set, and against float64 to 1 ulp). PoCL 3.0 calls its exp (_cl_exp), around which every live vector register
 * is spilled and reloaded: the call and its spills were ~25 % of the rasterizer's samples (docs/perf_notes.md §40).
 * docs/perf_notes.md §22's inline exp (Cephes' polynomial, on AVX2) changed the bits and did not pay. */
#ifndef RASTER_EXP_INLINE
#if REINGS_CLANG_BUILTINS && defined(__FMA__)
#define RASTER_EXP_INLINE 2
#else
#define RASTER_EXP_INLINE 0
#endif
#endif
#if RASTER_EXP_INLINE
#if RASTER_VEC == 8
typedef uint8 vu;
#define AS_VF as_float8
#define AS_VI as_int8
#define AS_VU as_uint8
#else
typedef uint16 vu;
#define AS_VF as_float16
#define AS_VI as_int16
#define AS_VU as_uint16
#endif
/* Only operators: PoCL 3.0 calls OpenCL's fma and conversions as it calls exp (docs/perf_notes.md §17). Each
 * a * b + c below is one fused multiply-add by OpenCL's FP_CONTRACT (on by default: clang's fmuladd, one vfmadd
 * where the target has FMA, __FMA__), and only those: a product whose sum is in another statement is rounded on
 * its own. rint(t) for |t| < 2^22 is (t + 1.5 2^23) - 1.5 2^23 in round-to-nearest-even, and the sum's low
 * mantissa bits are rint(t) as an integer. The exponent bits in unsigned arithmetic: a lane out of range (x below
 * -104, above 100, inf) wraps instead of overflowing, and its value is selected out at the end. */
/* exp_scaled(x, &n): Sleef's 1 + u with exp(x) = (1 + u) 2^n, n = rint(x / ln 2) (two's complement), the part both
 * forms below share */
inline vf exp_scaled(vf x, vu *n) {
    const vf t = x * 1.442695040888963407359924681001892137f; /* rounded alone, as Sleef's d * R_LN2f */
    const vf big = t + 12582912.0f;                          /* 1.5 2^23: |t| < 151 here (else selected out) */
    *n = AS_VU(big) - 0x4b400000u;                           /* rint(t), two's complement */
    const vf q = big - 12582912.0f;                          /* the same, as a float (exact) */
    vf s = q * -0.693145751953125f + x;
    s = q * -1.428606765330187045e-06f + s;
    vf u = s * 0.000198527617612853646278381f + 0.00139304355252534151077271f;
    u = u * s + 0.00833336077630519866943359f;
    u = u * s + 0.0416664853692054748535156f;
    u = u * s + 0.166666671633720397949219f;
    u = u * s + 0.5f;
    const vf s2 = s * s;
    u = u * s2 + s;
    return u + 1.0f;
}
inline vf exp_inline(vf x) {
    vu n;
    vf u = exp_scaled(x, &n);
    const vu h = AS_VU(AS_VI(n) >> 1); /* floor(n / 2): 2^n as 2^h 2^(n - h), each in the exponent's range */
    u = u * AS_VF((h << 23) + 0x3f800000u);
    u = u * AS_VF(((n - h) << 23) + 0x3f800000u);
    u = SEL(u, (vf)(0.0f), x < -104.0f);
    return SEL(u, (vf)(INFINITY), x > 100.0f);
}
/* exp_splat(x) (RASTER_EXP_INLINE 2): exp_inline's value, bit for bit, for every x in [-87, 88], where 2^n is one
 * normal float and the one product u 2^n is exact as Sleef's two are; below -87 (and NaN) it takes x = -87, a finite
 * value; above 88 unspecified. The rasterizer's lanes outside [-87, 0] never pass its pixel test (ALPHA_CUT_LN puts
 * every blended power above -6; the backward clamps its powers to 0 and zeroes those lanes' cotangents), so they
 * only need a finite value there: 8 operations fewer than exp_inline's range handling. */
inline vf exp_splat(vf x) {
    x = SEL((vf)(-87.0f), x, x >= -87.0f);
    vu n;
    const vf u = exp_scaled(x, &n);
    return u * AS_VF((n << 23) + 0x3f800000u);
}
#if RASTER_EXP_INLINE == 2
#define VEXP(x) exp_splat(x)
#else
#define VEXP(x) exp_inline(x)
#endif
#else
#define VEXP(x) exp(x)
#endif

/* A pixel vector is a block of BW x BH pixels (RASTER_BLOCK_H rows of RASTER_VEC / RASTER_BLOCK_H);
 * lane l is the block's pixel (l % BW, l / BW). Vector c is block row c / BPR, block column c % BPR. */
#if RASTER_VEC % RASTER_BLOCK_H || TILE_SIZE % RASTER_BLOCK_H || TILE_SIZE % (RASTER_VEC / RASTER_BLOCK_H)
#error "RASTER_BLOCK_H must divide RASTER_VEC and the tile, and RASTER_VEC / RASTER_BLOCK_H the tile"
#endif
#define BH RASTER_BLOCK_H
#define BW (RASTER_VEC / RASTER_BLOCK_H)
#define BPR (TILE_SIZE / BW)            /* pixel vectors per block row */
#define NVEC (TILE_PIXELS / RASTER_VEC) /* pixel vectors per tile */
#define VEC_X(c) (((c) % BPR) * BW)     /* tile-relative pixel column of vector c's lane 0 */
#define VEC_Y(c) (((c) / BPR) * BH)     /* tile-relative pixel row of vector c's lane 0 */
#if NVEC > 32 /* 16 or 32 at 16 or 8 lanes in a 16 x 16 tile */
#error "the CPU schedule keeps a set of a tile's vectors in 32 bits: TILE_PIXELS / RASTER_VEC <= 32"
#endif
typedef uint vset; /* a set of a tile's vectors as the bits of an integer (RASTER_CUT_MASK) */
#define VSET_LOW(m) low_bit(m)
#define ILX (ILANES % BW) /* lane l's column and row in its block */
#define ILY (ILANES / BW)

/* The block rows [*r0, *r1] and block columns [*c0, *c1] (tile-relative) of a Gaussian's box;
 * returns 0 when the box misses the tile. */
inline int box_in_tile(float16 g, int x0, int y0, int *r0, int *r1, int *c0, int *c1) {
    const int xlo = (int)g.sa - x0, xhi = (int)g.sb - x0, ylo = (int)g.sc - y0, yhi = (int)g.sd - y0;
    *r0 = IMAX(ylo, 0) / BH;
    *r1 = IMIN(yhi, TILE_SIZE - 1);
    *c0 = IMAX(xlo, 0) / BW;
    *c1 = IMIN(xhi, TILE_SIZE - 1);
    if (xhi < xlo || *c1 < 0 || *r1 < IMAX(ylo, 0) || xlo > TILE_SIZE - 1) return 0;
    *r1 /= BH;
    *c1 /= BW;
    return 1;
}

/* A vector's offsets from the Gaussian's centre to its pixels' centres, g - (pixel + 0.5), the centre
 * exact: each pixel gets the same value, and so the same power, at every block shape. */
#define VEC_CX(x) ((vf)((float)(x)) + (VCVT(ILX) + 0.5f)) /* the lanes' pixel centres, vector at column x */
#define VEC_CY(y) ((vf)((float)(y)) + (VCVT(ILY) + 0.5f))
#define VEC_DX(g, x) ((vf)((g).s0) - VEC_CX(x))
#define VEC_DY(g, y) ((vf)((g).s1) - VEC_CY(y))
#ifndef RASTER_CENTRES
#define RASTER_CENTRES 1
#endif
/* The offsets of block column cc / block row r of the tile at (x0, y0): RASTER_CENTRES, from a table of the tile's
 * pixel centres made once per tile (CENTRES, the same expressions, the same bits), else computed where used. */
#if RASTER_CENTRES
#define CENTRES                                                                               \
    vf cx_[BPR], cy_[TILE_SIZE / BH];                                                         \
    for (int q_ = 0; q_ < BPR; ++q_) cx_[q_] = VEC_CX(x0 + q_ * BW);                          \
    for (int q_ = 0; q_ < TILE_SIZE / BH; ++q_) cy_[q_] = VEC_CY(y0 + q_ * BH);
#define DXC(g, cc) ((vf)((g).s0) - cx_[cc])
#define DYC(g, r) ((vf)((g).s1) - cy_[r])
#else
#define CENTRES
#define DXC(g, cc) VEC_DX(g, x0 + (cc) * BW)
#define DYC(g, r) VEC_DY(g, y0 + (r) * BH)
#endif
/* a vector's powers from its offsets (one expression for every caller: the same contraction, the same bits) */
#define VEC_POWER(g, dx, dy) (-0.5f * ((g).s2 * (dx) * (dx) + (g).s4 * (dy) * (dy)) - (g).s3 * (dx) * (dy))

/* RASTER_CUT_MASK's first walk of Gaussian g's box [r0, r1] x [c0, c1] (block rows / columns, x0 / y0 the tile's
 * origin): each vector c's power into pw[c], and bit c of hit set where PASSES(power, c) (an int, 0 or 1), with no
 * branch per vector */
#define BOX_TESTS(pw, hit, PASSES)                                                            \
    for (int r = r0; r <= r1; ++r) {                                                          \
        const vf dy = DYC(g, r);                                                              \
        for (int cc = c0; cc <= c1; ++cc) {                                                   \
            const int c = r * BPR + cc;                                                       \
            const vf dx = DXC(g, cc);                                                         \
            const vf power = VEC_POWER(g, dx, dy);                                            \
            (pw)[c] = power;                                                                  \
            (hit) |= (vset)(PASSES(power, c)) << c;                                           \
        }                                                                                     \
    }

__kernel void rasterize_fwd(__global const float16 *packed,      // [N] records of raster_prep_one (project_fwd or rasterize_prep)
                            __global const int *tile_ranges,     // [T, 2]
                            __global const int *gid_from_isect,  // [K]
                            __global const int *emit_from_isect, // [K]
                            const int width, const int height, const int tiles_x, const int n_tiles,
                            const float bg_r, const float bg_g, const float bg_b,
                            __global float *out_rgb,   // [H, W, 3]
                            __global float *out_depth, // [H, W]
                            __global float *out_alpha, // [H, W]
                            __global float *out_T,     // [H, W]
                            __global int *out_last,    // [H, W]
                            __global float *imp_emit,  // [K] (RASTER_IMPORTANCE only)
                            __global uint *hits)       // [K] (RASTER_HITS: each visited pair's vector set)
{
#if !RASTER_HITS
    (void)hits;
#endif
    /* a 2D range (tx, ty): no div/rem of the tile id (LLVM's `freeze`, which Oclgrind rejects) */
    const int tx = get_global_id(0), ty = get_global_id(1);
    const int tile = ty * tiles_x + tx;
    if (tx >= tiles_x || tile >= n_tiles) return;
    const int x0 = tx * TILE_SIZE, y0 = ty * TILE_SIZE;
    CENTRES
    /* T > 0: active; T < 0: stopped (|T| is final); pixels outside the image start stopped */
    vf Tv[NVEC], Rv[NVEC], Gv[NVEC], Bv[NVEC], Dv[NVEC];
    vi Lv[NVEC];
    int n_active = 0;
    for (int c = 0; c < NVEC; ++c) {
        const int py = y0 + VEC_Y(c), px = x0 + VEC_X(c);
        const vi inside = (ILX + px < width) & (ILY + py < height);
        Tv[c] = SEL((vf)(-1.0f), (vf)(1.0f), inside);
        Rv[c] = Gv[c] = Bv[c] = Dv[c] = (vf)(0.0f);
        Lv[c] = (vi)(0);
        n_active += hcount(inside);
    }
    const int start = tile_ranges[2 * tile], end = tile_ranges[2 * tile + 1];
    int i = start;
    for (; i < end && n_active > 0; ++i) {
#if RASTER_PREFETCH
        if (i + RASTER_PREFETCH < end) __builtin_prefetch(packed + gid_from_isect[i + RASTER_PREFETCH]);
#endif
        const float16 g = packed[gid_from_isect[i]];
        const int kk = i - start + 1;
        int r0, r1, c0, c1;
        vf imp = (vf)(0.0f);
        if (box_in_tile(g, x0, y0, &r0, &r1, &c0, &c1)) {
#if RASTER_CUT_MASK
            /* the box's powers and cut tests first, without a branch per vector (each test's outcome is data, and
             * a branch on it was mispredicted often); then the vectors that passed, in the same order */
            vf pw[NVEC];
            vset hit = 0;
#if RASTER_ALPHA_CUT
#define FWD_PASSES(power, c) vany(((power) >= g.se) & (Tv[c] > 0.0f)) /* the cut, and a lane not stopped */
#else
#define FWD_PASSES(power, c) 1
#endif
            BOX_TESTS(pw, hit, FWD_PASSES);
#undef FWD_PASSES
#if RASTER_HITS
            hits[i] = hit; /* the set the backward of this forward walks */
#endif
            for (; hit; hit &= hit - 1) {
                {
                    const int c = VSET_LOW(hit);
                    const vf T = Tv[c];
                    const vf power = pw[c];
#else
            for (int r = r0; r <= r1; ++r) {
                const vf dy = DYC(g, r);
                for (int cc = c0; cc <= c1; ++cc) {
                    const int c = r * BPR + cc;
                    const vf T = Tv[c];
                    const vf dx = DXC(g, cc);
                    const vf power = VEC_POWER(g, dx, dy);
#if RASTER_ALPHA_CUT
                    /* the power cut (ALPHA_CUT_LN), and the lanes already stopped (T < 0): every lane fails ok below */
                    if (!vany((power >= g.se) & (T > 0.0f))) continue;
#endif
#endif
                    const vf a = g.s5 * VEXP(power); /* once: VMIN names its argument twice */
                    const vf alpha = VMIN(a, (vf)(ALPHA_MAX));
                    const vi ok = (T > 0.0f) & (power <= 0.0f) & (alpha >= ALPHA_MIN);
                    /* no test of any(ok) here: past the cut test a lane nearly always passes, and a vector
                     * with none adds zeros (w = 0) and keeps T and last: the same bytes, one any() less */
                    const vf Tn = T * (1.0f - alpha);
                    const vi stop = ok & (Tn < T_MIN);
                    const vi blend = ok & ~stop;
                    const vf w = SEL((vf)(0.0f), alpha * T, blend);
                    Rv[c] += w * g.s6;
                    Gv[c] += w * g.s7;
                    Bv[c] += w * g.s8;
                    Dv[c] += w * g.s9;
                    imp += w;
                    Tv[c] = SEL(SEL(T, -T, stop), Tn, blend);
                    Lv[c] = SEL(Lv[c], (vi)(kk), blend);
                    if (vany(stop)) n_active -= hcount(stop);
                }
            }
        }
#if RASTER_HITS
        else
            hits[i] = 0; /* the box misses the tile */
#endif
#if RASTER_IMPORTANCE
        imp_emit[emit_from_isect[i]] = hsum(imp);
#endif
    }
#if RASTER_IMPORTANCE
    for (; i < end; ++i) imp_emit[emit_from_isect[i]] = 0.0f;
#endif
    for (int c = 0; c < NVEC; ++c) {
        const int py0 = y0 + VEC_Y(c), px0 = x0 + VEC_X(c);
        if (py0 >= height) break;
        const vf T = fabs(Tv[c]);
        float tT[RASTER_VEC], tD[RASTER_VEC], tA[RASTER_VEC], tR[RASTER_VEC], tG[RASTER_VEC], tB[RASTER_VEC];
        int tL[RASTER_VEC];
        PSTOREV(T, tT);
        PSTOREV(Dv[c], tD);
        PSTOREV(1.0f - T, tA);
        PSTOREV(Rv[c] + T * bg_r, tR);
        PSTOREV(Gv[c] + T * bg_g, tG);
        PSTOREV(Bv[c] + T * bg_b, tB);
        PSTOREVI(Lv[c], tL);
#if RASTER_ROW_IO && BW == 4
        if (px0 + BW <= width && py0 + BH <= height) { /* the whole block inside: a row of 4 pixels at a time */
            for (int r = 0; r < BH; ++r) {
                const int p = (py0 + r) * width + px0;
                GSTORE4(PLOAD4(r, tT), 0, out_T + p);
                GSTORE4(PLOAD4(r, tD), 0, out_depth + p);
                GSTORE4(PLOAD4(r, tA), 0, out_alpha + p);
                GSTORE4I(PLOAD4I(r, tL), 0, out_last + p);
                const float4 R4 = PLOAD4(r, tR), G4 = PLOAD4(r, tG), B4 = PLOAD4(r, tB);
                GSTORE4(((float4)(R4.x, G4.x, B4.x, R4.y)), 0, out_rgb + 3 * p);
                GSTORE4(((float4)(G4.y, B4.y, R4.z, G4.z)), 0, out_rgb + 3 * p + 4);
                GSTORE4(((float4)(B4.z, R4.w, G4.w, B4.w)), 0, out_rgb + 3 * p + 8);
            }
            continue;
        }
#endif
        for (int l = 0; l < RASTER_VEC; ++l) {
            const int px = px0 + l % BW, py = py0 + l / BW;
            if (px >= width || py >= height) continue;
            const int p = py * width + px;
            out_T[p] = tT[l];
            out_depth[p] = tD[l];
            out_alpha[p] = tA[l];
            out_last[p] = tL[l];
            out_rgb[3 * p] = tR[l];
            out_rgb[3 * p + 1] = tG[l];
            out_rgb[3 * p + 2] = tB[l];
        }
    }
}

/* RASTER_BWD_SPLIT (CPU schedule with RASTER_CUT_MASK; the full backward): each Gaussian's vectors walked twice, the
 * recursion (T, R, d/d alpha, the opacity sum) first, keeping each vector's w and d/d power, then the colour and
 * geometry sums from them: fewer live values per walk, the same bits. One walk holds ten sums and about ten of the
 * Gaussian's values besides its vectors' state: more than AVX2's 16 vector registers, and the rest went to the stack
 * at every vector (2 AVX2 cores, Zen 3: 0.86-0.89 of the backward's time split, docs/perf_notes.md §44). Default
 * on for x86-64 targets without AVX-512 (16 vector registers), the measured case; off elsewhere (AVX-512's and
 * aarch64's 32 registers: not measured split). */
#ifndef RASTER_BWD_SPLIT
#if defined(__x86_64__) && !defined(__AVX512F__)
#define RASTER_BWD_SPLIT 1
#else
#define RASTER_BWD_SPLIT 0
#endif
#endif
#define BWD_SPLIT (RASTER_BWD_SPLIT && RASTER_CUT_MASK && !RASTER_BWD_OPACITY)
/* the geometry's sums of one vector: d/d (A, B, C) of the conic and d/d (u, v) of the mean, from d/d power vp */
#define BWD_GEOMETRY_SUMS(dx, dy, vp)                                                                  \
    do {                                                                                               \
        a_A -= 0.5f * (dx) * (dx) * (vp);                                                              \
        a_B -= (dx) * (dy) * (vp);                                                                     \
        a_C -= 0.5f * (dy) * (dy) * (vp);                                                              \
        a_u -= (g.s2 * (dx) + g.s3 * (dy)) * (vp);                                                     \
        a_v -= (g.s3 * (dx) + g.s4 * (dy)) * (vp);                                                     \
    } while (0)

/* One tile of rasterize_bwd with the cotangents scaled by sv and the colours, depths and outputs by
 * sk (see "Overflow" at the top); writes the records of positions [start, *stop_at) and returns 1 if
 * one of them is not finite. Called with literal 1s first, so that the common case compiles to the
 * unscaled loop. */
static inline __attribute__((always_inline)) int
bwd_tile(__global const float16 *packed, __global const int *gid_from_isect, __global const int *emit_from_isect,
         const int width, const int height, __global const float *out_rgb, __global const float *out_depth,
         __global const float *out_T, __global const int *out_last, __global const float *v_rgb,
         __global const float *v_depth, __global const float *v_alpha, const int v_mask, __global float *v_emit,
         __global const float *v_depth_o, __global float *v_emit_o, __global const uint *hits, const int use_hits,
         const int x0, const int y0, const int start, int *stop_at, const float sv, const float sk) {
#if !RASTER_HITS
    (void)hits;
    (void)use_hits;
#endif
    /* per pixel: T before the current Gaussian; R = v.(output - blended so far) - v_alpha T_final;
     * last (0 outside the image: never valid); the cotangents (all scaled: v by sv, colours by sk) */
    vf Tv[NVEC], Rv[NVEC], VR[NVEC], VG[NVEC], VB[NVEC], VD[NVEC];
#if RASTER_BWD_DEPTH_O
    vf RO[NVEC], VO[NVEC]; /* v_depth_o's own R and cotangent */
#else
    (void)v_depth_o;
    (void)v_emit_o;
#endif
    vi Lv[NVEC];
    vi lmax = (vi)(0);
    CENTRES
    for (int c = 0; c < NVEC; ++c) {
        const int py0 = y0 + VEC_Y(c), px0 = x0 + VEC_X(c);
        float vr[RASTER_VEC], vg[RASTER_VEC], vb[RASTER_VEC], vd[RASTER_VEC], R[RASTER_VEC];
        float vo[RASTER_VEC], ro[RASTER_VEC];
        int L[RASTER_VEC];
        for (int l = 0; l < RASTER_VEC; ++l) {
            vr[l] = vg[l] = vb[l] = vd[l] = R[l] = 0.0f;
            vo[l] = ro[l] = 0.0f;
            L[l] = 0;
        }
#if RASTER_ROW_IO && BW == 4
        /* the whole block inside the image and no scaling (the first, literal-1 instance): a row of 4
         * pixels at a time, each lane's R formed by the scalar loop's expression (the same bits) */
        const int rows = sv == 1.0f && sk == 1.0f && px0 + BW <= width && py0 + BH <= height ? BH : 0;
        for (int r = 0; r < rows; ++r) {
            const int p = (py0 + r) * width + px0;
            float4 r4 = (float4)(0.0f);
            if (v_mask & 1) {
                const float4 a = GLOAD4(0, v_rgb + 3 * p), b = GLOAD4(1, v_rgb + 3 * p), e = GLOAD4(2, v_rgb + 3 * p);
                const float4 oa = GLOAD4(0, out_rgb + 3 * p), ob = GLOAD4(1, out_rgb + 3 * p),
                             oe = GLOAD4(2, out_rgb + 3 * p);
                const float4 vr4 = (float4)(a.x, a.w, b.z, e.y), vg4 = (float4)(a.y, b.x, b.w, e.z),
                             vb4 = (float4)(a.z, b.y, e.x, e.w);
                r4 += vr4 * (float4)(oa.x, oa.w, ob.z, oe.y) + vg4 * (float4)(oa.y, ob.x, ob.w, oe.z) +
                      vb4 * (float4)(oa.z, ob.y, oe.x, oe.w);
                PSTORE4(vr4, r, vr);
                PSTORE4(vg4, r, vg);
                PSTORE4(vb4, r, vb);
            }
            if (v_mask & 2) {
                const float4 vd4 = GLOAD4(0, v_depth + p);
                r4 += vd4 * GLOAD4(0, out_depth + p);
                PSTORE4(vd4, r, vd);
            }
            if (v_mask & 4) r4 -= GLOAD4(0, v_alpha + p) * GLOAD4(0, out_T + p);
            PSTORE4(r4, r, R);
#if RASTER_BWD_DEPTH_O
            {
                float4 q4 = (float4)(0.0f);
                const float4 vo4 = GLOAD4(0, v_depth_o + p);
                q4 += vo4 * GLOAD4(0, out_depth + p);
                PSTORE4(vo4, r, vo);
                PSTORE4(q4, r, ro);
            }
#endif
            PSTORE4I(GLOAD4I(0, out_last + p), r, L);
        }
        for (int l = rows ? RASTER_VEC : 0; l < RASTER_VEC; ++l) {
#else
        for (int l = 0; l < RASTER_VEC; ++l) {
#endif
            const int px = px0 + l % BW, py = py0 + l / BW;
            if (px >= width || py >= height) continue;
            const int p = py * width + px;
            float r = 0.0f;
            if (v_mask & 1) {
                vr[l] = scaled(v_rgb[3 * p], sv);
                vg[l] = scaled(v_rgb[3 * p + 1], sv);
                vb[l] = scaled(v_rgb[3 * p + 2], sv);
                r += vr[l] * scaled(out_rgb[3 * p], sk) + vg[l] * scaled(out_rgb[3 * p + 1], sk) +
                     vb[l] * scaled(out_rgb[3 * p + 2], sk);
            }
            if (v_mask & 2) {
                vd[l] = scaled(v_depth[p], sv);
                r += vd[l] * scaled(out_depth[p], sk);
            }
            if (v_mask & 4) r -= scaled(v_alpha[p], sv) * scaled(out_T[p], sk);
            R[l] = r;
#if RASTER_BWD_DEPTH_O
            {   /* as a depth-only backward forms its R: 0 + v d */
                float q = 0.0f;
                vo[l] = scaled(v_depth_o[p], sv);
                q += vo[l] * scaled(out_depth[p], sk);
                ro[l] = q;
            }
#endif
            L[l] = out_last[p];
        }
        Tv[c] = (vf)(1.0f);
        Rv[c] = PLOADV(R);
        VR[c] = PLOADV(vr);
        VG[c] = PLOADV(vg);
        VB[c] = PLOADV(vb);
        VD[c] = PLOADV(vd);
#if RASTER_BWD_DEPTH_O
        RO[c] = PLOADV(ro);
        VO[c] = PLOADV(vo);
#endif
        (void)vo;
        (void)ro;
        Lv[c] = PLOADVI(L);
        lmax = IMAX(lmax, Lv[c]);
    }
    /* Gaussians at positions >= max(last) touch no pixel: their records are 0 */
    *stop_at = start + hmax(lmax);
    const float iv = 1.0f / sv, ik = 1.0f / sk; /* exact: powers of two */
    int bad = 0;
    for (int i = start; i < *stop_at; ++i) {
#if RASTER_PREFETCH
        if (i + RASTER_PREFETCH < *stop_at) __builtin_prefetch(packed + gid_from_isect[i + RASTER_PREFETCH]);
#endif
        const float16 g = packed[gid_from_isect[i]];
        const float cr = scaled(g.s6, sk), cg = scaled(g.s7, sk), cb = scaled(g.s8, sk);
        const float cz = scaled(g.s9, sk);
        const int k = i - start;
        vf a_u = 0.0f, a_v = 0.0f, a_A = 0.0f, a_B = 0.0f, a_C = 0.0f;
        vf a_r = 0.0f, a_g = 0.0f, a_b = 0.0f, a_o = 0.0f, a_z = 0.0f;
#if RASTER_BWD_DEPTH_O
        vf a_oo = 0.0f; /* v_depth_o's d/d opacity */
#endif
        int r0, r1, c0, c1;
#if RASTER_CUT_MASK
        /* as the forward: the box's tests first, without branches (a vector with no lane both before its pixel's
         * last and above the cut has no ok lane, and with finite inputs would add zeros: an infinite cotangent or
         * colour could make such a lane's 0 * inf a NaN, which the rescaled pass then redid), then the vectors
         * past them. RASTER_HITS, use_hits: the tests of the forward's set of the pair instead of the box's. The
         * set holds every vector the tests pass (a lane before its pixel's last was not stopped at this Gaussian
         * in the forward), so the outcome is the same set. */
        vf pw[NVEC];
        vset hit = 0;
#if RASTER_ALPHA_CUT
#define BWD_PASSES(power, c) vany(((vi)(k) < Lv[c]) & ((power) >= g.se)) /* before the pixel's last, the cut */
#else
#define BWD_PASSES(power, c) vany((vi)(k) < Lv[c])
#endif
#if RASTER_HITS
        if (use_hits) { /* the set's powers and tests first, as the box's walk (one loop of each kind: 0.93-0.98 of
                         * the backward's time against each power where it is used, docs/perf_notes.md §33) */
            for (vset m = hits[i]; m; m &= m - 1) {
                const int c = VSET_LOW(m);
                const vf power = VEC_POWER(g, DXC(g, c % BPR), DYC(g, c / BPR));
                pw[c] = power;
                hit |= (vset)(BWD_PASSES(power, c)) << c;
            }
        } else
#endif
        if (box_in_tile(g, x0, y0, &r0, &r1, &c0, &c1)) {
            BOX_TESTS(pw, hit, BWD_PASSES);
        }
#undef BWD_PASSES
#if BWD_SPLIT
        vf wv[NVEC], vpv[NVEC]; /* the first walk's w and d/d power per vector, for the second */
        const vset hit0 = hit;
#endif
        { /* the vectors past the tests (this block's braces pair with the #else branch's box loop) */
            for (; hit; hit &= hit - 1) {
                {
                    const int c = VSET_LOW(hit);
                    const vi valid = (vi)(k) < Lv[c];
                    const vf dy = DYC(g, c / BPR);
                    const vf dx = DXC(g, c % BPR);
                    const vf power = pw[c];
#else
        if (box_in_tile(g, x0, y0, &r0, &r1, &c0, &c1)) {
            for (int r = r0; r <= r1; ++r) {
                const vf dy = DYC(g, r);
                for (int cc = c0; cc <= c1; ++cc) {
                    const int c = r * BPR + cc;
                    const vi valid = (vi)(k) < Lv[c];
                    if (!vany(valid)) continue;
                    const vf dx = DXC(g, cc);
                    const vf power = VEC_POWER(g, dx, dy);
#if RASTER_ALPHA_CUT
                    if (!vany(power >= g.se)) continue; /* the power cut (ALPHA_CUT_LN): every lane fails ok below */
#endif
#endif
                    /* power <= 0 in every ok lane (the same G there); a lane that is not ok (a conic that is
                     * not positive definite, uploaded through the stage API, can give power > 88) must not
                     * make G = inf, which its zero va would turn into a NaN in a_o */
                    const vf G = VEXP(VMIN(power, (vf)(0.0f)));
                    const vf a = g.s5 * G;
                    const vf alpha = VMIN(a, (vf)(ALPHA_MAX));
                    const vi ok = valid & (power <= 0.0f) & (alpha >= ALPHA_MIN);
                    /* no any(ok) test (as in the forward): a vector with no ok lane adds zeros */
                    const vf T = Tv[c], R = Rv[c];
                    const vf w = SEL((vf)(0.0f), alpha * T, ok);
                    const vf vr = VR[c], vg = VG[c], vb = VB[c], vd = VD[c];
                    const vf vc = vr * cr + vg * cg + vb * cb + vd * cz;
                    const vf Rn = R - vc * w;
#if !RASTER_BWD_OPACITY && !BWD_SPLIT
                    a_r += vr * w;
                    a_g += vg * w;
                    a_b += vb * w;
                    a_z += vd * w;
#endif
                    /* d out / d alpha: T c - (behind) / (1 - alpha); alpha <= ALPHA_MAX bounds 1/(1-alpha) */
                    const vf va = SEL((vf)(0.0f), T * vc - Rn / (1.0f - alpha), ok & (a <= ALPHA_MAX));
                    a_o += va * G;
#if RASTER_BWD_DEPTH_O
                    {   /* the same recursion on v_depth_o alone (its colour cotangents are 0) */
                        const vf RoV = RO[c], vco = VO[c] * cz;
                        const vf Ron = RoV - vco * w;
                        const vf vao = SEL((vf)(0.0f), T * vco - Ron / (1.0f - alpha), ok & (a <= ALPHA_MAX));
                        a_oo += vao * G;
                        RO[c] = SEL(RoV, Ron, ok);
                    }
#endif
#if !RASTER_BWD_OPACITY
                    const vf vp = va * alpha; /* d/d power (alpha = o exp(power) when unclamped) */
#if BWD_SPLIT
                    wv[c] = w;
                    vpv[c] = vp;
                    (void)dx;
                    (void)dy;
#else
                    BWD_GEOMETRY_SUMS(dx, dy, vp);
#endif
#endif
                    Tv[c] = SEL(T, T * (1.0f - alpha), ok);
                    Rv[c] = SEL(R, Rn, ok);
                }
            }
        }
#if BWD_SPLIT
        /* the second walk: the colour and geometry sums from the first's w and d/d power, each sum's terms in the
         * first walk's order (the same vectors, the same expressions: the same bits) */
        for (vset m = hit0; m; m &= m - 1) {
            const int c = VSET_LOW(m);
            const vf dy = DYC(g, c / BPR);
            const vf dx = DXC(g, c % BPR);
            const vf w = wv[c], vp = vpv[c];
            a_r += VR[c] * w;
            a_g += VG[c] * w;
            a_b += VB[c] * w;
            a_z += VD[c] * w;
            BWD_GEOMETRY_SUMS(dx, dy, vp);
        }
#endif
        /* back to unscaled units: the d/d alpha path carries sv * sk, the colour/depth path sv */
        float o[V_RECORD];
#if RASTER_BWD_OPACITY
        for (int f = 0; f < V_RECORD; ++f) o[f] = 0.0f;
        o[8] = hsum(a_o) * iv * ik;
        (void)a_u; (void)a_v; (void)a_A; (void)a_B; (void)a_C; (void)a_r; (void)a_g; (void)a_b; (void)a_z;
#else
        o[0] = hsum(a_u) * iv * ik;
        o[1] = hsum(a_v) * iv * ik;
        o[2] = hsum(a_A) * iv * ik;
        o[3] = hsum(a_B) * iv * ik;
        o[4] = hsum(a_C) * iv * ik;
        o[5] = hsum(a_r) * iv;
        o[6] = hsum(a_g) * iv;
        o[7] = hsum(a_b) * iv;
        o[8] = hsum(a_o) * iv * ik;
        o[9] = hsum(a_z) * iv;
#endif
        __global float *rec = v_emit + (size_t)emit_from_isect[i] * V_RECORD;
        for (int f = 0; f < V_RECORD; ++f) {
            bad |= !FINITE(o[f]);
            rec[f] = o[f];
        }
#if RASTER_BWD_DEPTH_O
        {   /* v_depth_o's record: as a RASTER_BWD_OPACITY backward writes it */
            const float so = hsum(a_oo) * iv * ik;
            bad |= !FINITE(so);
            __global float *ro_rec = v_emit_o + (size_t)emit_from_isect[i] * V_RECORD;
            for (int f = 0; f < V_RECORD; ++f) ro_rec[f] = f == 8 ? so : 0.0f;
        }
#endif
    }
    return bad;
}

#undef BWD_SPLIT
#undef BWD_GEOMETRY_SUMS

/* Pass 1 of rasterize_bwd: bounds of |v| (*mv_out) and of |colour, depth, output, 1| (*mk_out)
 * over the tile's pixels and its Gaussians [start, stop_at); fmax skips NaN (a NaN input stays NaN). */
static inline void bwd_tile_bounds(__global const float16 *packed, __global const int *gid_from_isect,
                                   const int width, const int height, __global const float *out_rgb,
                                   __global const float *out_depth, __global const float *v_rgb,
                                   __global const float *v_depth, __global const float *v_alpha, const int v_mask,
                                   __global const float *v_depth_o,
                                   const int x0, const int y0, const int start, const int stop_at, float *mv_out,
                                   float *mk_out) {
    float mv = 0.0f, mk = 1.0f;
    for (int r = 0; r < TILE_SIZE && y0 + r < height; ++r) {
        for (int x = 0; x < TILE_SIZE && x0 + x < width; ++x) {
            const int p = (y0 + r) * width + x0 + x;
            if (v_mask & 1)
                for (int ch = 0; ch < 3; ++ch) {
                    mv = fmax(mv, fabs(sat_inf(v_rgb[3 * p + ch])));
                    mk = fmax(mk, fabs(sat_inf(out_rgb[3 * p + ch])));
                }
            if (v_mask & 2) {
                mv = fmax(mv, fabs(sat_inf(v_depth[p])));
                mk = fmax(mk, fabs(sat_inf(out_depth[p])));
            }
            if (v_mask & 4) mv = fmax(mv, fabs(sat_inf(v_alpha[p])));
#if RASTER_BWD_DEPTH_O
            mv = fmax(mv, fabs(sat_inf(v_depth_o[p])));
            mk = fmax(mk, fabs(sat_inf(out_depth[p])));
#else
            (void)v_depth_o;
#endif
        }
    }
    for (int i = start; i < stop_at; ++i) {
        const float16 g = packed[gid_from_isect[i]];
        mk = fmax(mk, fmax(fmax(fabs(sat_inf(g.s6)), fabs(sat_inf(g.s7))),
                           fmax(fabs(sat_inf(g.s8)), fabs(sat_inf(g.s9)))));
    }
    *mv_out = mv;
    *mk_out = mk;
}

__kernel void rasterize_bwd(__global const float16 *packed,      // [N] records of raster_prep_one (project_fwd or rasterize_prep)
                            __global const int *tile_ranges,     // [T, 2]
                            __global const int *gid_from_isect,  // [K]
                            __global const int *emit_from_isect, // [K]
                            const int width, const int height, const int tiles_x, const int n_tiles,
                            __global const float *out_rgb,   // [H, W, 3] forward output
                            __global const float *out_depth, // [H, W]
                            __global const float *out_T,     // [H, W]
                            __global const int *out_last,    // [H, W]
                            __global const float *v_rgb,     // [H, W, 3] (bit 0 of v_mask)
                            __global const float *v_depth,   // [H, W]    (bit 1)
                            __global const float *v_alpha,   // [H, W]    (bit 2)
                            const int v_mask,
                            __global float *v_emit,          // [K, V_RECORD]
                            __global const float *v_depth_o, // [H, W] (RASTER_BWD_DEPTH_O)
                            __global float *v_emit_o,        // [K, V_RECORD] (RASTER_BWD_DEPTH_O)
                            __global const uint *hits,       // [K] rasterize_fwd's sets (RASTER_HITS)
                            const int use_hits)              // 1: `hits` are this frame's forward's
{
    /* a 2D range (tx, ty): no div/rem of the tile id (LLVM's `freeze`, which Oclgrind rejects) */
    const int tx = get_global_id(0), ty = get_global_id(1);
    const int tile = ty * tiles_x + tx;
    if (tx >= tiles_x || tile >= n_tiles) return;
    const int x0 = tx * TILE_SIZE, y0 = ty * TILE_SIZE;
    const int start = tile_ranges[2 * tile], end = tile_ranges[2 * tile + 1];
    int stop_at = start;
    /* pass 0 unscaled (exact: the common case ends here); pass 1 only if a record overflowed and the
     * bounds call for scaling (otherwise the non-finite record came from non-finite inputs) */
    if (bwd_tile(packed, gid_from_isect, emit_from_isect, width, height, out_rgb, out_depth, out_T, out_last,
                 v_rgb, v_depth, v_alpha, v_mask, v_emit, v_depth_o, v_emit_o, hits, use_hits, x0, y0, start, &stop_at,
                 1.0f, 1.0f)) {
        float mv, mk;
        bwd_tile_bounds(packed, gid_from_isect, width, height, out_rgb, out_depth, v_rgb, v_depth, v_alpha,
                        v_mask, v_depth_o, x0, y0, start, stop_at, &mv, &mk);
        const float sv = pow2_scale_down(mv, 28), sk = pow2_scale_down(mk, 28); /* below 2^29 */
        if (sv != 1.0f || sk != 1.0f)
            bwd_tile(packed, gid_from_isect, emit_from_isect, width, height, out_rgb, out_depth, out_T, out_last,
                     v_rgb, v_depth, v_alpha, v_mask, v_emit, v_depth_o, v_emit_o, hits, use_hits, x0, y0, start,
                     &stop_at, sv, sk);
    }
    for (int i = stop_at; i < end; ++i) {
        __global float *rec = v_emit + (size_t)emit_from_isect[i] * V_RECORD;
        for (int f = 0; f < V_RECORD; ++f) rec[f] = 0.0f;
#if RASTER_BWD_DEPTH_O
        __global float *ro_rec = v_emit_o + (size_t)emit_from_isect[i] * V_RECORD;
        for (int f = 0; f < V_RECORD; ++f) ro_rec[f] = 0.0f;
#endif
    }
}

#else
/* ========================================================================================== */
/* GPU schedule: a 256-work-item group per tile, a work-item per pixel                         */

#define WARP 32
#if REINGS_NV_PTX
#define NPART (TILE_PIXELS / WARP) /* one partial per warp */
inline float shfl_xor(float x, int m) {
    float r;
    asm volatile("shfl.sync.bfly.b32 %0, %1, %2, 0x1f, 0xffffffff;" : "=f"(r) : "f"(x), "r"(m));
    return r;
}
inline int warp_any(int p) {
    int r;
    asm volatile("{\n\t.reg .pred q, a;\n\tsetp.ne.s32 q, %1, 0;\n\t"
                 "vote.sync.any.pred a, q, 0xffffffff;\n\tselp.s32 %0, 1, 0, a;\n\t}"
                 : "=r"(r) : "r"(p));
    return r;
}
inline float warp_sum(float x) {
    for (int m = WARP / 2; m >= 1; m >>= 1) x += shfl_xor(x, m);
    return x;
}
/* The warp sums of 16 values per lane with 16 shuffles instead of 16 butterflies (80): at each
 * step a lane keeps half of its values and receives its partner's copy of them (the other half
 * goes to the partner), so after the steps 16, 8, 4, 2 a lane holds one value, field
 * warp_field(lane), and step 1 completes it. Every partial is the butterfly's own pair sum
 * (x_l + x_(l^m), the same tree), so the result has warp_sum's bits (docs/perf_notes.md §16). */
inline int warp_field(int lane) {
    return (lane >> 1) & 15; /* bits 4, 3, 2, 1 of the lane: the halves kept at steps 16, 8, 4, 2 */
}
inline float warp_sum16(const float *x, const int lane) {
    float a[8], b[4], c[2];
    const int h16 = lane & 16, h8 = lane & 8, h4 = lane & 4, h2 = lane & 2;
    for (int i = 0; i < 8; ++i) a[i] = (h16 ? x[8 + i] : x[i]) + shfl_xor(h16 ? x[i] : x[8 + i], 16);
    for (int i = 0; i < 4; ++i) b[i] = (h8 ? a[4 + i] : a[i]) + shfl_xor(h8 ? a[i] : a[4 + i], 8);
    for (int i = 0; i < 2; ++i) c[i] = (h4 ? b[2 + i] : b[i]) + shfl_xor(h4 ? b[i] : b[2 + i], 4);
    float d = (h2 ? c[1] : c[0]) + shfl_xor(h2 ? c[0] : c[1], 2);
    return d + shfl_xor(d, 1);
}
#else
#define NPART 1
#endif

/* Sum NF values over the work-group (nthreads work-items) into part[(p * batch + j) * NF + f] (p: partial index).
 * NVIDIA: butterfly shuffles per warp (skipped when no lane contributes), lane 0 stores.
 * Portable: a local-memory tree (red: [NF * nthreads]), barriers inside; every work-item
 * must call it (uniform control flow). */
inline void group_sum(const float *vals, const int NF, const int any_nz, const int j, const int batch,
                      __local float *part, __local float *red, const int lid, const int nthreads) {
#if REINGS_NV_PTX
    const int w = lid / WARP, lane = lid % WARP;
    (void)red;
    (void)nthreads;
#if RASTER_BWD_TRANSPOSE
    if (NF > 1) { /* one transposed sum of all fields (at most 16); lanes 2f write field f */
        float x[16];
        for (int f = 0; f < 16; ++f) x[f] = f < NF ? vals[f] : 0.0f;
        const float s = warp_any(any_nz) ? warp_sum16(x, lane) : 0.0f;
        const int f = warp_field(lane);
        if (!(lane & 1) && f < NF) part[(w * batch + j) * NF + f] = s;
        return;
    }
#endif
    if (warp_any(any_nz)) {
        for (int f = 0; f < NF; ++f) {
            const float s = warp_sum(vals[f]);
            if (lane == 0) part[(w * batch + j) * NF + f] = s;
        }
    } else if (lane == 0) {
        for (int f = 0; f < NF; ++f) part[(w * batch + j) * NF + f] = 0.0f;
    }
#else
    (void)any_nz;
    for (int f = 0; f < NF; ++f) red[f * nthreads + lid] = vals[f];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int s = nthreads / 2; s > 0; s >>= 1) {
        if (lid < s)
            for (int f = 0; f < NF; ++f) red[f * nthreads + lid] += red[f * nthreads + lid + s];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (lid == 0)
        for (int f = 0; f < NF; ++f) part[j * NF + f] = red[f * nthreads];
    /* the next call's first write to red[lid] follows this barrier */
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
}

inline int in_box(float16 g, int px, int py) {
    return (float)px >= g.sa && (float)px <= g.sb && (float)py >= g.sc && (float)py <= g.sd;
}

__kernel __attribute__((reqd_work_group_size(TILE_PIXELS, 1, 1))) void
rasterize_fwd(__global const float16 *packed,      // [N] records of raster_prep_one (project_fwd or rasterize_prep)
              __global const int *tile_ranges,     // [T, 2]
              __global const int *gid_from_isect,  // [K]
              __global const int *emit_from_isect, // [K]
              const int width, const int height, const int tiles_x, const int n_tiles,
              const float bg_r, const float bg_g, const float bg_b,
              __global float *out_rgb,   // [H, W, 3]
              __global float *out_depth, // [H, W]
              __global float *out_alpha, // [H, W]
              __global float *out_T,     // [H, W]
              __global int *out_last,    // [H, W]
              __global float *imp_emit,  // [K] (RASTER_IMPORTANCE only)
              __global uint *hits)       // CPU schedule only
{
    (void)hits;
    __local float16 sh[FWD_BATCH];
    __local int n_done;
#if RASTER_IMPORTANCE
    __local float part[NPART * FWD_BATCH];
#if !REINGS_NV_PTX
    __local float red[TILE_PIXELS];
#else
    __local float *red = 0;
#endif
#endif
    /* groups on a 2D range (tx, ty): no div/rem of the tile id (LLVM `freeze`, rejected by Oclgrind) */
    const int tx = get_group_id(0), ty = get_group_id(1);
    const int tile = ty * tiles_x + tx;
    const int lid = get_local_id(0);
    const int x0 = tx * TILE_SIZE, y0 = ty * TILE_SIZE;
    /* unsigned: a signed div/rem pair turns into LLVM `freeze` (Oclgrind rejects it) */
    const int px = x0 + (int)((uint)lid % TILE_SIZE), py = y0 + (int)((uint)lid / TILE_SIZE);
    const int inside = px < width && py < height;
    const float fx = (float)px + 0.5f, fy = (float)py + 0.5f;
    int active = inside;
    float T = 1.0f, cr = 0.0f, cg = 0.0f, cb = 0.0f, cd = 0.0f;
    int last = 0;
    const int start = tile_ranges[2 * tile], end = tile_ranges[2 * tile + 1];
    int b0 = start;
    for (; b0 < end; b0 += FWD_BATCH) {
        barrier(CLK_LOCAL_MEM_FENCE); /* the previous batch is done with sh / part / n_done */
        if (lid == 0) n_done = 0;
        barrier(CLK_LOCAL_MEM_FENCE);
        if (!active) atomic_inc(&n_done);
        const int nb = min(FWD_BATCH, end - b0);
        if (lid < nb) sh[lid] = packed[gid_from_isect[b0 + lid]];
        barrier(CLK_LOCAL_MEM_FENCE);
        if (n_done == TILE_PIXELS) break; /* uniform: whole tile saturated */
        for (int j = 0; j < nb; ++j) {
            const float16 g = sh[j];
            float w = 0.0f;
            if (active && in_box(g, px, py)) {
                const float dx = g.s0 - fx, dy = g.s1 - fy;
                const float power = -0.5f * (g.s2 * dx * dx + g.s4 * dy * dy) - g.s3 * dx * dy;
                const float alpha = fmin(ALPHA_MAX, g.s5 * exp(power));
                if (power <= 0.0f && alpha >= ALPHA_MIN) {
                    const float Tn = T * (1.0f - alpha);
                    if (Tn < T_MIN) {
                        active = 0;
                    } else {
                        w = alpha * T;
                        cr += w * g.s6;
                        cg += w * g.s7;
                        cb += w * g.s8;
                        cd += w * g.s9;
                        T = Tn;
                        last = b0 - start + j + 1;
                    }
                }
            }
#if RASTER_IMPORTANCE
            group_sum(&w, 1, w != 0.0f, j, FWD_BATCH, part, red, lid, TILE_PIXELS);
#endif
        }
#if RASTER_IMPORTANCE
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lid < nb) {
            float s = 0.0f;
            for (int p = 0; p < NPART; ++p) s += part[p * FWD_BATCH + lid];
            imp_emit[emit_from_isect[b0 + lid]] = s;
        }
#endif
    }
#if RASTER_IMPORTANCE
    /* after an early exit the remaining slots are 0 */
    for (int e = b0 + lid; e < end; e += TILE_PIXELS) imp_emit[emit_from_isect[e]] = 0.0f;
#endif
    if (inside) {
        const int p = py * width + px;
        out_rgb[3 * p] = cr + T * bg_r;
        out_rgb[3 * p + 1] = cg + T * bg_g;
        out_rgb[3 * p + 2] = cb + T * bg_b;
        out_depth[p] = cd;
        out_alpha[p] = 1.0f - T;
        out_T[p] = T;
        out_last[p] = last;
    }
}

/* BWD_PIX pixels per work-item in rasterize_bwd (GPU schedule): a work-group of BWD_THREADS =
 * TILE_PIXELS / BWD_PIX work-items per tile; work-item lid holds the pixels of column lid % TILE_SIZE
 * in rows (lid / TILE_SIZE) * BWD_PIX + q, q < BWD_PIX (a warp: 2 * BWD_PIX whole rows), adds its
 * pixels' values of a Gaussian (pixel 0's, then + pixel 1's, ...) and takes part in one group sum per
 * Gaussian for all of them: the per-Gaussian warp sums (19-25 % of the backward on an H100,
 * docs/perf_notes.md §28) are done once per BWD_PIX pixels. BWD_PIX 1: one pixel per work-item, the
 * records of earlier sessions byte for byte. */
#ifndef BWD_PIX
#define BWD_PIX 1
#endif
#if BWD_PIX != 1 && BWD_PIX != 2 && BWD_PIX != 4
#error "BWD_PIX must be 1, 2 or 4"
#endif
#define BWD_THREADS (TILE_PIXELS / BWD_PIX)
#if BWD_BATCH > BWD_THREADS
#error "BWD_BATCH must not exceed the backward's work-group (TILE_PIXELS / BWD_PIX)"
#endif
#if REINGS_NV_PTX
#define BWD_NPART (BWD_THREADS / WARP) /* one partial per warp */
#else
#define BWD_NPART 1
#endif

/* One tile of rasterize_bwd (the calling work-group) with the cotangents scaled by sv and the
 * colours, depths and outputs by sk (see "Overflow" at the top): writes the records of positions
 * [start, stop_at) and sets *bad if one is not finite. Every work-item calls it (barriers inside).
 * Called with literal 1s first, so that the common case compiles to the unscaled loop. The
 * per-pixel arguments are the work-item's BWD_PIX pixels. */
static inline __attribute__((always_inline)) void
bwd_group(__global const float16 *packed, __global const int *gid_from_isect,
          __global const int *emit_from_isect, __global const float *out_rgb, __global const float *out_depth,
          __global const float *out_T, __global const float *v_rgb, __global const float *v_depth,
          __global const float *v_alpha, const int v_mask, __global float *v_emit,
          __global const float *v_depth_o, __global float *v_emit_o, const int *inside, const int *pix,
          const int *px, const int *py, const int *last, const int start, const int stop_at, const int lid,
          __local float16 *sh, __local float *part, __local float *red, volatile __local int *bad, const float sv,
          const float sk) {
    /* per pixel: the cotangents (scaled by sv), R = v.(output - blended so far) - v_alpha T_final
     * (scaled by sv sk), T before the current Gaussian */
    float fx[BWD_PIX], fy[BWD_PIX], vr[BWD_PIX], vg[BWD_PIX], vb[BWD_PIX], vd[BWD_PIX], R[BWD_PIX], T[BWD_PIX];
#if RASTER_BWD_DEPTH_O
    /* v_depth_o's own cotangent and R, formed as a depth-only backward forms them: 0 + v d */
    float vo[BWD_PIX], Ro[BWD_PIX];
#else
    (void)v_depth_o;
    (void)v_emit_o;
#endif
    for (int q = 0; q < BWD_PIX; ++q) {
        fx[q] = (float)px[q] + 0.5f;
        fy[q] = (float)py[q] + 0.5f;
        vr[q] = vg[q] = vb[q] = vd[q] = R[q] = 0.0f;
        T[q] = 1.0f;
        const int p = pix[q];
        if (inside[q]) {
            if (v_mask & 1) {
                vr[q] = scaled(v_rgb[3 * p], sv);
                vg[q] = scaled(v_rgb[3 * p + 1], sv);
                vb[q] = scaled(v_rgb[3 * p + 2], sv);
                R[q] += vr[q] * scaled(out_rgb[3 * p], sk) + vg[q] * scaled(out_rgb[3 * p + 1], sk) +
                        vb[q] * scaled(out_rgb[3 * p + 2], sk);
            }
            if (v_mask & 2) {
                vd[q] = scaled(v_depth[p], sv);
                R[q] += vd[q] * scaled(out_depth[p], sk);
            }
            if (v_mask & 4) R[q] -= scaled(v_alpha[p], sv) * scaled(out_T[p], sk);
        }
#if RASTER_BWD_DEPTH_O
        vo[q] = Ro[q] = 0.0f;
        if (inside[q]) {
            vo[q] = scaled(v_depth_o[p], sv);
            Ro[q] += vo[q] * scaled(out_depth[p], sk);
        }
#endif
    }
    const float iv = 1.0f / sv, ik = 1.0f / sk; /* exact: powers of two */
    for (int b0 = start; b0 < stop_at; b0 += BWD_BATCH) {
        const int nb = min(BWD_BATCH, stop_at - b0);
        barrier(CLK_LOCAL_MEM_FENCE); /* the previous batch (or call) is done with sh / part */
        if (lid < nb) {
            float16 g = packed[gid_from_isect[b0 + lid]];
            g.s6 = scaled(g.s6, sk); /* colours and depth scaled once per Gaussian */
            g.s7 = scaled(g.s7, sk);
            g.s8 = scaled(g.s8, sk);
            g.s9 = scaled(g.s9, sk);
            sh[lid] = g;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int j = 0; j < nb; ++j) {
            const float16 g = sh[j];
            const int k = b0 - start + j;
            float vals[BWD_FIELDS];
            for (int f = 0; f < BWD_FIELDS; ++f) vals[f] = 0.0f;
            int nz = 0;
            for (int q = 0; q < BWD_PIX; ++q) {
                if (!(k < last[q] && in_box(g, px[q], py[q]))) continue;
                const float dx = g.s0 - fx[q], dy = g.s1 - fy[q];
                const float power = -0.5f * (g.s2 * dx * dx + g.s4 * dy * dy) - g.s3 * dx * dy;
                const float G = exp(power);
                const float a = g.s5 * G;
                const float alpha = fmin(ALPHA_MAX, a);
                if (!(power <= 0.0f && alpha >= ALPHA_MIN)) continue;
                /* pixel 0's value, then + each later pixel's (BWD_PIX 1: the value itself) */
#define ACC(f, x) vals[f] = q ? vals[f] + (x) : (x)
                nz = 1;
                const float w = alpha * T[q];
                const float vc = vr[q] * g.s6 + vg[q] * g.s7 + vb[q] * g.s8 + vd[q] * g.s9;
                const float Rn = R[q] - vc * w;
                /* no gradient through the ALPHA_MAX clamp */
                const float va = a <= ALPHA_MAX ? T[q] * vc - Rn / (1.0f - alpha) : 0.0f;
#if RASTER_BWD_DEPTH_O
                {   /* the same recursion on v_depth_o alone (its colour cotangents are 0) */
                    const float vco = vo[q] * g.s9;
                    const float Ron = Ro[q] - vco * w;
                    const float vao = a <= ALPHA_MAX ? T[q] * vco - Ron / (1.0f - alpha) : 0.0f;
                    ACC(V_RECORD, vao * G);
                    Ro[q] = Ron;
                }
#endif
#if RASTER_BWD_OPACITY
                ACC(0, va * G); /* field 8 only */
#else
                ACC(5, vr[q] * w);
                ACC(6, vg[q] * w);
                ACC(7, vb[q] * w);
                ACC(9, vd[q] * w);
                ACC(8, va * G);
                const float vp = va * alpha;
                ACC(2, -0.5f * dx * dx * vp);
                ACC(3, -dx * dy * vp);
                ACC(4, -0.5f * dy * dy * vp);
                ACC(0, -(g.s2 * dx + g.s3 * dy) * vp);
                ACC(1, -(g.s3 * dx + g.s4 * dy) * vp);
#endif
#undef ACC
                T[q] *= 1.0f - alpha;
                R[q] = Rn;
            }
            group_sum(vals, BWD_FIELDS, nz, j, BWD_BATCH, part, red, lid, BWD_THREADS);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
#if RASTER_BWD_OPACITY
        for (int e = lid; e < nb * V_RECORD; e += BWD_THREADS) { /* fields other than 8: 0 */
            const int j = e / V_RECORD, f = e - j * V_RECORD;
            if (f == 8) continue;
            v_emit[(size_t)emit_from_isect[b0 + j] * V_RECORD + f] = 0.0f;
        }
        for (int j = lid; j < nb; j += BWD_THREADS) {
            float s = 0.0f;
            for (int p = 0; p < BWD_NPART; ++p) s += part[p * BWD_BATCH + j];
            s *= iv;
            s *= ik;
            if (!isfinite(s)) atomic_or(bad, 1);
            v_emit[(size_t)emit_from_isect[b0 + j] * V_RECORD + 8] = s;
        }
#else
        for (int e = lid; e < nb * V_RECORD; e += BWD_THREADS) {
            const int j = e / V_RECORD, f = e - j * V_RECORD;
            float s = 0.0f;
            for (int p = 0; p < BWD_NPART; ++p) s += part[(p * BWD_BATCH + j) * BWD_FIELDS + f];
            /* back to unscaled units: the colour/depth fields (5, 6, 7, 9) carry sv, the rest sv sk */
            s *= iv;
            if (f < 5 || f == 8) s *= ik;
            if (!isfinite(s)) atomic_or(bad, 1);
            v_emit[(size_t)emit_from_isect[b0 + j] * V_RECORD + f] = s;
        }
#if RASTER_BWD_DEPTH_O
        /* v_depth_o's records, as a RASTER_BWD_OPACITY backward writes them */
        for (int e = lid; e < nb * V_RECORD; e += BWD_THREADS) {
            const int j = e / V_RECORD, f = e - j * V_RECORD;
            if (f == 8) continue;
            v_emit_o[(size_t)emit_from_isect[b0 + j] * V_RECORD + f] = 0.0f;
        }
        for (int j = lid; j < nb; j += BWD_THREADS) {
            float s = 0.0f;
            for (int p = 0; p < BWD_NPART; ++p) s += part[(p * BWD_BATCH + j) * BWD_FIELDS + V_RECORD];
            s *= iv;
            s *= ik;
            if (!isfinite(s)) atomic_or(bad, 1);
            v_emit_o[(size_t)emit_from_isect[b0 + j] * V_RECORD + 8] = s;
        }
#endif
#endif
    }
}

__kernel __attribute__((reqd_work_group_size(BWD_THREADS, 1, 1))) void
rasterize_bwd(__global const float16 *packed,      // [N] records of raster_prep_one (project_fwd or rasterize_prep)
              __global const int *tile_ranges,     // [T, 2]
              __global const int *gid_from_isect,  // [K]
              __global const int *emit_from_isect, // [K]
              const int width, const int height, const int tiles_x, const int n_tiles,
              __global const float *out_rgb,   // [H, W, 3] forward output
              __global const float *out_depth, // [H, W]
              __global const float *out_T,     // [H, W]
              __global const int *out_last,    // [H, W]
              __global const float *v_rgb,     // [H, W, 3] (bit 0 of v_mask)
              __global const float *v_depth,   // [H, W]    (bit 1)
              __global const float *v_alpha,   // [H, W]    (bit 2)
              const int v_mask,
              __global float *v_emit,          // [K, V_RECORD]
              __global const float *v_depth_o, // [H, W] (RASTER_BWD_DEPTH_O)
              __global float *v_emit_o,        // [K, V_RECORD] (RASTER_BWD_DEPTH_O)
              __global const uint *hits,       // CPU schedule only
              const int use_hits)
{
    (void)hits;
    (void)use_hits;
    __local float16 sh[BWD_BATCH];
    __local float part[BWD_NPART * BWD_BATCH * BWD_FIELDS];
#if !REINGS_NV_PTX
    __local float red[BWD_FIELDS * BWD_THREADS];
#else
    __local float *red = 0;
#endif
    __local int max_last, bad, mv_bits, mk_bits;
    /* groups on a 2D range (tx, ty): no div/rem of the tile id (LLVM `freeze`, rejected by Oclgrind) */
    const int tx = get_group_id(0), ty = get_group_id(1);
    const int tile = ty * tiles_x + tx;
    const int lid = get_local_id(0);
    const int x0 = tx * TILE_SIZE, y0 = ty * TILE_SIZE;
    /* this work-item's pixels: column lid % TILE_SIZE, rows (lid / TILE_SIZE) * BWD_PIX + q
     * (unsigned: a signed div/rem pair turns into LLVM `freeze`, which Oclgrind rejects) */
    int inside[BWD_PIX], pix[BWD_PIX], px[BWD_PIX], py[BWD_PIX], last[BWD_PIX];
    int my_last = 0;
    for (int q = 0; q < BWD_PIX; ++q) {
        px[q] = x0 + (int)((uint)lid % TILE_SIZE);
        py[q] = y0 + (int)((uint)lid / TILE_SIZE) * BWD_PIX + q;
        inside[q] = px[q] < width && py[q] < height;
        pix[q] = py[q] * width + px[q]; /* read only when inside */
        last[q] = inside[q] ? out_last[pix[q]] : 0;
        my_last = max(my_last, last[q]);
    }
    if (lid == 0) {
        max_last = 0;
        bad = 0;
        mv_bits = 0;
        mk_bits = as_int(1.0f);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    atomic_max(&max_last, my_last);
    barrier(CLK_LOCAL_MEM_FENCE);
    const int start = tile_ranges[2 * tile], end = tile_ranges[2 * tile + 1];
    const int stop_at = start + max_last; /* positions >= max(last) touch no pixel */
    /* pass 0 unscaled (exact: the common case ends here); pass 1 only if a record overflowed and the
     * bounds call for scaling (otherwise the non-finite record came from non-finite inputs). The
     * branches read local values after a barrier: uniform over the work-group. */
    bwd_group(packed, gid_from_isect, emit_from_isect, out_rgb, out_depth, out_T, v_rgb, v_depth, v_alpha, v_mask,
              v_emit, v_depth_o, v_emit_o, inside, pix, px, py, last, start, stop_at, lid, sh, part, red, &bad, 1.0f,
              1.0f);
    barrier(CLK_LOCAL_MEM_FENCE); /* bad is final */
    if (bad) {
        /* bounds of |v| and of |colour, depth, output, 1| over the tile; fmax skips NaN */
        float mv = 0.0f, mk = 0.0f;
        for (int q = 0; q < BWD_PIX; ++q) {
            if (!inside[q]) continue;
            const int p = pix[q];
            if (v_mask & 1)
                for (int ch = 0; ch < 3; ++ch) {
                    mv = fmax(mv, fabs(sat_inf(v_rgb[3 * p + ch])));
                    mk = fmax(mk, fabs(sat_inf(out_rgb[3 * p + ch])));
                }
            if (v_mask & 2) {
                mv = fmax(mv, fabs(sat_inf(v_depth[p])));
                mk = fmax(mk, fabs(sat_inf(out_depth[p])));
            }
            if (v_mask & 4) mv = fmax(mv, fabs(sat_inf(v_alpha[p])));
#if RASTER_BWD_DEPTH_O
            mv = fmax(mv, fabs(sat_inf(v_depth_o[p])));
            mk = fmax(mk, fabs(sat_inf(out_depth[p])));
#endif
        }
        for (int e = start + lid; e < stop_at; e += BWD_THREADS) {
            const float16 g = packed[gid_from_isect[e]];
            mk = fmax(mk, fmax(fmax(fabs(sat_inf(g.s6)), fabs(sat_inf(g.s7))),
                               fmax(fabs(sat_inf(g.s8)), fabs(sat_inf(g.s9)))));
        }
        atomic_max(&mv_bits, as_int(mv)); /* non-negative floats order like their bits */
        atomic_max(&mk_bits, as_int(mk));
        barrier(CLK_LOCAL_MEM_FENCE);
        const float sv = pow2_scale_down(as_float(mv_bits), 28), sk = pow2_scale_down(as_float(mk_bits), 28);
        if (sv != 1.0f || sk != 1.0f)
            bwd_group(packed, gid_from_isect, emit_from_isect, out_rgb, out_depth, out_T, v_rgb, v_depth, v_alpha,
                      v_mask, v_emit, v_depth_o, v_emit_o, inside, pix, px, py, last, start, stop_at, lid, sh, part,
                      red, &bad, sv, sk);
    }
    /* Gaussians at positions >= max(last): zero records */
    for (int e = stop_at + lid; e < end; e += BWD_THREADS) {
        __global float *rec = v_emit + (size_t)emit_from_isect[e] * V_RECORD;
        for (int f = 0; f < V_RECORD; ++f) rec[f] = 0.0f;
#if RASTER_BWD_DEPTH_O
        __global float *ro_rec = v_emit_o + (size_t)emit_from_isect[e] * V_RECORD;
        for (int f = 0; f < V_RECORD; ++f) ro_rec[f] = 0.0f;
#endif
    }
}
#endif
