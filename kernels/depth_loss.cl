/* depth_loss.cl: DNGaussian's global-local depth loss (docs/method.md §2.4)
 *     L = w_local * local(p_local) + w_global * global(p_global)
 * and its gradient w.r.t. the rendered depth, for one [H, W] depth against its (constant) target.
 *
 * Must match reings.backends.reference_loss.global_local_depth_loss (float64), including its
 * detach rules and documented deviations (tests/test_depth_loss_kernel.py). One term with patch
 * size p, for each input X in {depth, target}:
 *     P      = the (H/p)*(W/p) non-overlapping p x p patches (n = p*p values each, leftovers dropped)
 *     u      = P - patch mean                                          (not detached)
 *     s_all  = unbiased std of ALL patch values (the patchified region) (not detached)
 *     d      = local:  unbiased per-patch std of u + 0.01 s_all         (not detached)
 *              global: unbiased std of the WHOLE image X (detached) + 0.01 s_all
 *     X_hat  = u / d
 *     diff   = depth_hat - target_hat; mask = |diff| > margin (no gradient); cnt = #mask (global)
 *     term   = sum(diff^2 over mask) / cnt; cnt == 0 -> term 0 and gradient 0 (torch: NaN)
 * Backward of one term (a layer-norm backward), g = mask ? 2 diff / cnt : 0, per patch m:
 *     gd_m   = -sum_m(g u) / d_m^2
 *     gu     = g / d + [local and s_patch > 0] gd_m / ((n - 1) s_patch) * u   (0 at zero std: torch NaN)
 *     gP     = gu - mean_m(gu) + [s_all > 0] 0.01 sum_m'(gd_m') (P - mean_all) / ((N - 1) s_all)
 * mean_m(u) is 0 exactly in exact arithmetic and is taken as 0 in mean_m(gu). A constant input
 * (d = 0) makes every X_hat NaN: NaN fails the mask test, so such elements are simply unselected,
 * as in the reference.
 *
 * Kernels, launched in this order by reings.backends.opencl.losses.DepthLossCL (5 launches per
 * call; 3 with DL_FUSE, where each reduce runs in the last work-group of the kernel before it).
 * Blocks of "job" j: j = 0 the p_local patches, j = 1 the p_global patches, j = 2 the image
 * rows (1 x W blocks: the whole-image std of the global term).
 *   dl_block_stats   global (>= max blocks, 6): item (b, 2 j + input) -> the mean and the sum of
 *                    squared deviations of block b (two passes over the block, in `real`)
 *   dl_reduce_stats  global (DL_WG, 6), local (DL_WG, 1): per (job, input) the mean and unbiased
 *                    std over all blocks (equal-size blocks: mean of means, then
 *                    SS = sum SS_b + n sum (mean_b - mean)^2, exact combination, no cancellation)
 *   dl_patch_terms   global (>= max patches, 2): item (m, term) -> patch m's record (means, 1/d of
 *                    both inputs, per-patch std, #mask, sum diff^2, sum mdiff, sum mdiff * u with
 *                    mdiff = mask ? diff : 0)
 *   dl_reduce_terms  global (DL_WG, 2), local (DL_WG, 1): per term cnt and the term loss into
 *                    tstats (the host reads the loss from there), and the gradient as an affine
 *                    map per patch (A_m, B_m, C_m; E and mean_all per term: see the kernel)
 *   dl_grad          global (>= W, H) per pixel, or (H) per row with REINGS_CPU_SCHEDULE:
 *                    v_depth = w_local g_local + w_global g_global, OVERWRITTEN (0 outside both
 *                    patchified regions), plus s_scale times the smoothness gradient (below)
 *   depth_smooth_rows  (only when the loss is read) the depth_smooth term's numerator per row
 * Optional depth_smooth stage, DNGaussian's LLFF edge-aware smoothness
 * (reference_loss.depth_smooth_fwd_bwd): weights swx / swy from the target
 * (reference_loss.depth_smooth_weights / DepthSmoothWeights, computed once per view on the host),
 * folded into dl_grad's single write of v_depth (no extra launch on the training path).
 * Every reduction is per-block sums in a fixed order, then one work-group's lane-strided partials
 * and a fixed tree: deterministic, no atomics.
 *
 * Precision: with DL_FP64=1 (the host sets it where the device has cl_khr_fp64: PoCL, NVIDIA) all
 * statistics and per-pixel math are double, as the reference; only v_depth is rounded to float.
 * DL_FP64=0 (devices without doubles): float, with each input shifted by its first pixel before
 * any sum (exact for nearby values, so depth ~1e3 + small variation keeps its precision). Means
 * stored in bstats / sstats are of the shifted values (shift 0 with DL_FP64=1).
 *
 * Defines
 *   DL_FP64  1: double statistics (needs cl_khr_fp64); 0 (default): float with the shift
 *   DL_FUSE  1: dl_block_stats and dl_patch_terms run in work-groups of DL_WG, count their finished
 *            groups atomically (`done`, after each group's stores and a global fence), and the last
 *            group runs the following reduce (reduce_stats_one / reduce_terms_one, the functions the
 *            separate kernels run, with the same lanes: the same bits), reading the other groups'
 *            stores through volatile pointers; two launches fewer per call. The host sets it on the
 *            GPU schedule where such cross-group reads are known to work (quirks.volatile_status_words:
 *            NVIDIA, PoCL's CPUs); 0 (default) elsewhere and under Oclgrind (docs/perf_notes.md §26)
 *   DL_WG    work-group size of the two reduce kernels, a power of two (host: 1 on CPU devices,
 *            256 on GPUs; 64 here by default)
 *   DL_GROUP blocks per dl_block_stats item, their sums interleaved (the same bits; host: 8 on the CPU
 *            schedule without DL_FUSE, else 1)
 * Per-pixel weights (has_wt = 1, `wt` [H, W] float32 in [0, 1]: the depth prior's confidence
 * map, reference_loss.depth_norm_loss_fwd_bwd(weight=)): each selected element's squared error is
 * weighted, term = sum(wt diff^2 over mask) / cnt (cnt still counts the selected elements), so
 * g = mask ? 2 wt diff / cnt : 0 and every `mdiff` above becomes mask ? wt diff : 0. The
 * statistics (patch means and stds) are unweighted. has_wt = 0 never reads `wt`: the unweighted loss.
 * Not handled: masks / invalid target pixels (a NaN target element is just never selected, but
 * it poisons that input's statistics, as in the reference).
 */
#pragma OPENCL FP_CONTRACT OFF

#include "common.h"

#ifndef DL_FP64
#define DL_FP64 0
#endif
#ifndef DL_WG
#define DL_WG 64
#endif
#if DL_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#define RC(x) x
#define SHIFT(src) ((real)0)
#else
typedef float real;
#define RC(x) x##f
#define SHIFT(src) ((real)(src)[0])
#endif

#define DL_RATIO RC(0.01)  /* DNGaussian: scale + 0.01 * std(all patch values) */

#ifndef DL_FUSE
#define DL_FUSE 0
#endif
#ifndef DL_UNROLL
#define DL_UNROLL 8 /* lane-strided sums: loads issued this many at a time, then added in order */
#endif

/* acc += EXPR(i) for i = lane, lane + DL_WG, ... < M, in that order (the same rounding as the plain
 * loop), with the loads of DL_UNROLL terms issued before their adds: a volatile load (DL_FUSE) is
 * never reordered or merged by the compiler, and one at a time each would wait a memory latency. */
#define STRIDED_SUM(T, acc, lane, M, EXPR)                                           \
    do {                                                                             \
        int i_ = (lane);                                                             \
        for (; i_ + (DL_UNROLL - 1) * DL_WG < (M); i_ += DL_UNROLL * DL_WG) {        \
            T v_[DL_UNROLL];                                                         \
            for (int k_ = 0; k_ < DL_UNROLL; ++k_) {                                 \
                const int i = i_ + k_ * DL_WG;                                       \
                v_[k_] = (EXPR);                                                     \
            }                                                                        \
            for (int k_ = 0; k_ < DL_UNROLL; ++k_) (acc) += v_[k_];                  \
        }                                                                            \
        for (; i_ < (M); i_ += DL_WG) {                                              \
            const int i = i_;                                                        \
            (acc) += (EXPR);                                                         \
        }                                                                            \
    } while (0)

#if DL_FUSE
/* what the last work-group reads of the other groups' stores: volatile (NVIDIA's volatile global
 * loads are not served from L1; PoCL's CPUs are coherent; docs/perf_notes.md §20, §26) */
#define XWG __global volatile
#else
#define XWG __global
#endif

/* Block geometry of job j: bw x bh blocks, nbx per block row, M blocks. */
static void job_geom(const int job, const int W, const int H, const int pl, const int pg,
                     int *bw, int *bh, int *nbx, int *M)
{
    if (job == 2) {
        *bw = W; *bh = 1; *nbx = 1; *M = H;
        return;
    }
    const int p = job == 0 ? pl : pg;
    *bw = p; *bh = p; *nbx = W / p; *M = (W / p) * (H / p);
}

/* q = a / b, r = a % b, unsigned: a signed div/rem pair turns into LLVM `freeze`, which Oclgrind
 * rejects (as in rasterize.cl) */
static void divmod(const uint a, const uint b, int *q, int *r)
{
    const uint qq = a / b;
    *q = (int)qq;
    *r = (int)(a - qq * b);
}

static void tree_sum(__local real *s, const int lane)
{
    for (int off = DL_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lane < off) s[lane] += s[lane + off];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* Block b of (job, input) ji: its mean (- shift) and sum of squared deviations into bstats. */
static void block_stats_one(__global const float *depth, __global const float *target, __global real *bstats,
                            const int b, const int ji, const int W, const int H, const int pl, const int pg,
                            const int Bcap)
{
    int bw, bh, nbx, M;
    job_geom(ji >> 1, W, H, pl, pg, &bw, &bh, &nbx, &M);
    if (!(b < M)) return;
    __global const float *src = (ji & 1) ? target : depth;
    const real k0 = SHIFT(src);
    int bx, by;
    divmod((uint)b, (uint)nbx, &by, &bx);
    const int x0 = bx * bw, y0 = by * bh;
    real s = 0;
    for (int y = y0; y < y0 + bh; ++y)
        for (int x = x0; x < x0 + bw; ++x) s += (real)src[y * W + x] - k0;
    const real mean = s / (real)(bw * bh);
    real ss = 0;
    for (int y = y0; y < y0 + bh; ++y)
        for (int x = x0; x < x0 + bw; ++x) {
            const real u = ((real)src[y * W + x] - k0) - mean;
            ss += u * u;
        }
    bstats[2 * (ji * Bcap + b)] = mean;
    bstats[2 * (ji * Bcap + b) + 1] = ss;
}

#ifndef DL_GROUP
#define DL_GROUP 1
#endif
#if DL_GROUP > 1
/* DL_GROUP > 1 (the host's CPU schedule, without DL_FUSE): item (g, ji) takes blocks [g DL_GROUP, (g + 1) DL_GROUP)
 * of (job, input) ji together, their sums interleaved element by element: each block's sums in block_stats_one's
 * order (the same expressions, so the same bits), DL_GROUP independent chains of double adds in flight instead of
 * one (a chain of dependent adds waits each add's latency; docs/perf_notes.md §41). A group past the last block
 * repeats the last block's loads in its spare lanes and stores nothing for them. */
static void block_stats_group(__global const float *depth, __global const float *target, __global real *bstats,
                              const int g, const int ji, const int W, const int H, const int pl, const int pg,
                              const int Bcap)
{
    int bw, bh, nbx, M;
    job_geom(ji >> 1, W, H, pl, pg, &bw, &bh, &nbx, &M);
    const int b0 = g * DL_GROUP;
    if (!(b0 < M)) return;
    __global const float *src = (ji & 1) ? target : depth;
    const real k0 = SHIFT(src);
    __global const float *base[DL_GROUP];
    real s[DL_GROUP], mean[DL_GROUP], ss[DL_GROUP];
    for (int q = 0; q < DL_GROUP; ++q) {
        int bx, by;
        divmod((uint)min(b0 + q, M - 1), (uint)nbx, &by, &bx);
        base[q] = src + by * bh * W + bx * bw;
        s[q] = 0;
        ss[q] = 0;
    }
    for (int y = 0; y < bh; ++y)
        for (int x = 0; x < bw; ++x)
            for (int q = 0; q < DL_GROUP; ++q) s[q] += (real)base[q][y * W + x] - k0;
    for (int q = 0; q < DL_GROUP; ++q) mean[q] = s[q] / (real)(bw * bh);
    for (int y = 0; y < bh; ++y)
        for (int x = 0; x < bw; ++x)
            for (int q = 0; q < DL_GROUP; ++q) {
                const real u = ((real)base[q][y * W + x] - k0) - mean[q];
                ss[q] += u * u;
            }
    for (int q = 0; q < DL_GROUP && b0 + q < M; ++q) {
        bstats[2 * (ji * Bcap + b0 + q)] = mean[q];
        bstats[2 * (ji * Bcap + b0 + q) + 1] = ss[q];
    }
}
#endif

/* A block's share of the combined sum of squares, SS_b + n (mean_b - mean)^2 (each record word loaded once). */
static real ss_term(const real ss_b, const real mean_b, const real mean, const real n)
{
    const real dm = mean_b - mean;
    return ss_b + n * dm * dm;
}

/* The statistics of (job, input) ji over all its blocks, by one work-group of DL_WG lanes (s: its
 * local array): sstats[ji] = (mean - shift, unbiased std). */
static void reduce_stats_one(XWG const real *bstats, __global real *sstats, __local real *s, const int lane,
                             const int ji, const int W, const int H, const int pl, const int pg, const int Bcap)
{
    int bw, bh, nbx, M;
    job_geom(ji >> 1, W, H, pl, pg, &bw, &bh, &nbx, &M);
    XWG const real *bs = bstats + 2 * ji * Bcap;
    real acc = 0;
    STRIDED_SUM(real, acc, lane, M, bs[2 * i]);
    s[lane] = acc;
    tree_sum(s, lane);
    const real mean = s[0] / (real)M;
    barrier(CLK_LOCAL_MEM_FENCE);  /* everyone has read s[0] before it is overwritten */
    const real n = (real)(bw * bh);
    acc = 0;
    STRIDED_SUM(real, acc, lane, M, ss_term(bs[2 * i + 1], bs[2 * i], mean, n));
    s[lane] = acc;
    tree_sum(s, lane);
    if (lane == 0) {
        sstats[2 * ji] = mean;
        sstats[2 * ji + 1] = sqrt(s[0] / ((real)M * n - (real)1));
    }
    barrier(CLK_LOCAL_MEM_FENCE);  /* s[0] read before a next call writes s */
}

#if DL_FUSE
/* The last of the launch's work-groups to finish (an atomic count of finished groups, after each
 * group's stores and a global fence) returns 1, and resets the count for the next launch. */
static int last_group(__global int *done, const int lane, __local int *flag)
{
    mem_fence(CLK_GLOBAL_MEM_FENCE);  /* every lane orders its own stores (the writer fences, as in CUDA's pattern) */
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);  /* this group's stores before its count */
    if (lane == 0) {
        mem_fence(CLK_GLOBAL_MEM_FENCE);
        const int total = (int)(get_num_groups(0) * get_num_groups(1));
        const int prev = atomic_inc(done);
        *flag = prev == total - 1;
        if (*flag) *done = 0;  /* every other group has counted: the next launch starts from 0 */
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const int last = *flag;
    if (last) mem_fence(CLK_GLOBAL_MEM_FENCE);
    return last;
}
#endif

/* DL_FUSE 0: item (b, ji) of a (>= max blocks, 6) range (DL_GROUP > 1: item (g, ji) of a (>= max blocks / DL_GROUP,
 * 6) range); dl_reduce_stats follows.
 * DL_FUSE 1: the same items in work-groups of (DL_WG, 1), and the last group to finish runs
 * dl_reduce_stats's six reductions in turn (the same lanes and order: the same bits). */
__kernel void dl_block_stats(__global const float *depth,   // [H, W] rendered depth
                             __global const float *target,  // [H, W] target (mono depth)
                             __global real *bstats,         // [6, Bcap, 2] (mean - shift, sum (x - mean)^2)
                             const int W, const int H, const int pl, const int pg, const int Bcap,
                             __global real *sstats,         // [6, 2] (DL_FUSE only)
                             __global int *done)            // [2] finished-group counts, 0 between launches (DL_FUSE only)
{
    const int b = get_global_id(0), ji = get_global_id(1);
#if DL_GROUP > 1
    if (ji < 6) block_stats_group(depth, target, bstats, b, ji, W, H, pl, pg, Bcap); /* b: a group of blocks */
#else
    if (ji < 6) block_stats_one(depth, target, bstats, b, ji, W, H, pl, pg, Bcap);
#endif
#if DL_FUSE
    __local real s[DL_WG];
    __local int flag;
    const int lane = get_local_id(0);
    if (!last_group(done, lane, &flag)) return;
    for (int j = 0; j < 6; ++j) reduce_stats_one(bstats, sstats, s, lane, j, W, H, pl, pg, Bcap);
#else
    (void)sstats;
    (void)done;
#endif
}

__kernel void dl_reduce_stats(__global const real *bstats,  // [6, Bcap, 2]
                              __global real *sstats,        // [6, 2] (mean - shift, unbiased std)
                              const int W, const int H, const int pl, const int pg, const int Bcap)
{
    __local real s[DL_WG];
    reduce_stats_one(bstats, sstats, s, get_local_id(0), get_group_id(1), W, H, pl, pg, Bcap);
}

/* d of patch m of input inp (0 depth, 1 target) in term t; *sp = its per-patch std (local term). */
static real patch_scale(__global const real *bstats, __global const real *sstats, const int t,
                        const int inp, const int m, const int n, const int Bcap, real *sp)
{
    const real s_all = sstats[2 * (2 * t + inp) + 1];
    if (t == 0) {
        *sp = sqrt(bstats[2 * ((2 * t + inp) * Bcap + m) + 1] / (real)(n - 1));
        return *sp + DL_RATIO * s_all;
    }
    *sp = 0;
    return sstats[2 * (4 + inp) + 1] + DL_RATIO * s_all;  /* detached whole-image std */
}

/* Per-patch record of dl_patch_terms (REC reals per patch and term). */
#define REC 8
#define R_MD 0   /* depth patch mean (- shift) */
#define R_MT 1   /* target patch mean (- shift) */
#define R_DD 2   /* 1 / depth d */
#define R_DT 3   /* 1 / target d */
#define R_SP 4   /* depth per-patch std (local term; 0 in the global term) */
#define R_SQ 5   /* sum of diff^2 over the mask */
#define R_A 6    /* sum of mdiff */
#define R_B 7    /* sum of mdiff * u */

/* Patch m of term t: its record (means, 1/d of both inputs, per-patch std, #mask, sums). */
static void patch_terms_one(__global const float *depth, __global const float *target, __global const real *bstats,
                            __global const real *sstats, __global int *pcnt, __global real *prec, const real margin,
                            const int m, const int t, const int W, const int H, const int pl, const int pg,
                            const int Bcap, __global const float *wt, const int has_wt)
{
    int p, unused, pw, M;
    job_geom(t, W, H, pl, pg, &p, &unused, &pw, &M);
    if (!(m < M)) return;
    const int n = p * p;
    real sp, spt;
    const real dd = patch_scale(bstats, sstats, t, 0, m, n, Bcap, &sp);
    const real dt = patch_scale(bstats, sstats, t, 1, m, n, Bcap, &spt);
    const real md = bstats[2 * ((2 * t) * Bcap + m)], mt = bstats[2 * ((2 * t + 1) * Bcap + m)];
    const real rd = (real)1 / dd, rt = (real)1 / dt;
    const real kd = SHIFT(depth), kt = SHIFT(target);
    int mx, my;
    divmod((uint)m, (uint)pw, &my, &mx);
    const int x0 = mx * p, y0 = my * p;
    int cnt = 0;
    real sq = 0, sa = 0, sb = 0;
    for (int y = y0; y < y0 + p; ++y)
        for (int x = x0; x < x0 + p; ++x) {
            const real u = ((real)depth[y * W + x] - kd) - md;
            const real v = ((real)target[y * W + x] - kt) - mt;
            const real diff = u * rd - v * rt;  /* the same expression as dl_grad's: same mask */
            if (FABSG(diff) > margin) {          /* NaN (a zero-std input) is never selected */
                const real wd = has_wt ? (real)wt[y * W + x] * diff : diff;  /* the weighted mdiff */
                cnt += 1;
                sq += wd * diff;
                sa += wd;
                sb += wd * u;
            }
        }
    __global real *r = prec + REC * (t * Bcap + m);
    pcnt[t * Bcap + m] = cnt;
    r[R_MD] = md; r[R_MT] = mt; r[R_DD] = rd; r[R_DT] = rt; r[R_SP] = sp;
    r[R_SQ] = sq; r[R_A] = sa; r[R_B] = sb;
}

/* Per term: cnt, the term loss, and the gradient as an affine map per patch,
 *   gP = A_m mdiff + B_m u + C_m + E (x - mean_all),
 *   A_m = (2/cnt) / d_m,  B_m = [local, s_patch > 0] gd_m / ((n - 1) s_patch),
 *   C_m = -mean_m(g / d) = -(2/cnt) sum_m(mdiff) / (d_m n),
 *   E   = [s_all > 0] 0.01 sum_m gd_m / ((N - 1) s_all),   gd_m = -(2/cnt) sum_m(mdiff u) / d_m^2;
 * all zero when cnt == 0. One work-group of DL_WG lanes per term (s, c: its local arrays). */
static void reduce_terms_one(__global const real *sstats, XWG const int *pcnt, XWG const real *prec,
                             __global real *pcoef, __global real *tstats, __local real *s, __local int *c,
                             const int lane, const int t, const int W, const int H, const int pl, const int pg,
                             const int Bcap)
{
    int p, unused, pw, M;
    job_geom(t, W, H, pl, pg, &p, &unused, &pw, &M);
    const int n = p * p;
    XWG const real *rec = prec + REC * t * Bcap;
    __global real *co = pcoef + 3 * t * Bcap;
    int ci = 0;
    STRIDED_SUM(int, ci, lane, M, pcnt[t * Bcap + i]);
    c[lane] = ci;
    for (int off = DL_WG / 2; off > 0; off >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (lane < off) c[lane] += c[lane + off];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const int cnt = c[0];
    real acc = 0;
    STRIDED_SUM(real, acc, lane, M, rec[REC * i + R_SQ]);
    s[lane] = acc;
    tree_sum(s, lane);
    const real sq = s[0];
    barrier(CLK_LOCAL_MEM_FENCE);
    const real scale = cnt > 0 ? (real)2 / (real)cnt : (real)0;
    acc = 0;
    for (int m0 = lane; m0 < M; m0 += DL_UNROLL * DL_WG) {
        /* the records of up to DL_UNROLL patches loaded first (see STRIDED_SUM), then used in order */
        real rdd[DL_UNROLL], rsp[DL_UNROLL], rb[DL_UNROLL], ra[DL_UNROLL];
        if (cnt > 0)
            for (int k = 0; k < DL_UNROLL; ++k) {
                const int m = m0 + k * DL_WG;
                if (m < M) {
                    XWG const real *r = rec + REC * m;
                    rdd[k] = r[R_DD]; rsp[k] = r[R_SP]; rb[k] = r[R_B]; ra[k] = r[R_A];
                }
            }
        for (int k = 0; k < DL_UNROLL; ++k) {
            const int m = m0 + k * DL_WG;
            if (!(m < M)) break;
            real a = 0, b = 0, cc = 0;
            if (cnt > 0) {  /* then every depth d_m > 0 (a zero d makes every element unselected) */
                const real d = (real)1 / rdd[k], sp = rsp[k];
                const real gd = -(scale * rb[k]) / (d * d);
                acc += gd;
                a = scale / d;
                b = (t == 0 && sp > (real)0) ? gd / ((real)(n - 1) * sp) : (real)0;
                cc = -(scale * ra[k]) / (d * (real)n);
            }
            co[3 * m] = a; co[3 * m + 1] = b; co[3 * m + 2] = cc;
        }
    }
    s[lane] = acc;
    tree_sum(s, lane);
    if (lane == 0) {
        const real s_all = sstats[2 * (2 * t) + 1];
        tstats[4 * t] = (real)cnt;
        tstats[4 * t + 1] = cnt > 0 ? sq / (real)cnt : (real)0;
        tstats[4 * t + 2] = (cnt > 0 && s_all > (real)0) ? DL_RATIO * s[0] / ((real)(M * n - 1) * s_all) : (real)0;
        tstats[4 * t + 3] = sstats[2 * (2 * t)];
    }
    barrier(CLK_LOCAL_MEM_FENCE);  /* s[0] and c[0] read before a next call writes them */
}

/* DL_FUSE 0: item (m, t) of a (>= max patches, 2) range; dl_reduce_terms follows.
 * DL_FUSE 1: the same items in work-groups of (DL_WG, 1), and the last group to finish runs
 * dl_reduce_terms's two reductions in turn (the same lanes and order: the same bits). */
__kernel void dl_patch_terms(__global const float *depth,   // [H, W]
                             __global const float *target,  // [H, W]
                             __global const real *bstats,   // [6, Bcap, 2]
                             __global const real *sstats,   // [6, 2]
                             __global int *pcnt,            // [2, Bcap] #mask per patch
                             __global real *prec,           // [2, Bcap, REC] per-patch record (R_*)
                             const real margin,
                             const int W, const int H, const int pl, const int pg, const int Bcap,
                             __global const float *wt,      // [H, W] per-pixel weights (read if has_wt)
                             const int has_wt,
                             __global real *pcoef,          // [2, Bcap, 3] (DL_FUSE only)
                             __global real *tstats,         // [2, 4] (DL_FUSE only)
                             __global int *done)            // [2] finished-group counts (DL_FUSE only)
{
    const int m = get_global_id(0), t = get_global_id(1);
    if (t < 2) patch_terms_one(depth, target, bstats, sstats, pcnt, prec, margin, m, t, W, H, pl, pg, Bcap, wt, has_wt);
#if DL_FUSE
    __local real s[DL_WG];
    __local int c[DL_WG];
    __local int flag;
    const int lane = get_local_id(0);
    if (!last_group(done + 1, lane, &flag)) return;
    for (int j = 0; j < 2; ++j) reduce_terms_one(sstats, pcnt, prec, pcoef, tstats, s, c, lane, j, W, H, pl, pg, Bcap);
#else
    (void)pcoef;
    (void)tstats;
    (void)done;
#endif
}

__kernel void dl_reduce_terms(__global const real *sstats,  // [6, 2]
                              __global const int *pcnt,     // [2, Bcap]
                              __global const real *prec,    // [2, Bcap, REC]
                              __global real *pcoef,         // [2, Bcap, 3] (A, B, C) per patch
                              __global real *tstats,        // [2, 4] (cnt, term loss, E, mean_all - shift)
                              const int W, const int H, const int pl, const int pg, const int Bcap)
{
    __local real s[DL_WG];
    __local int c[DL_WG];
    reduce_terms_one(sstats, pcnt, prec, pcoef, tstats, s, c, get_local_id(0), get_group_id(1), W, H, pl, pg, Bcap);
}

/* The gradient of term t at a pixel of patch m (xd, xt: the shifted depth and target there). */
static real term_grad(const real xd, const real xt, const real wv, __global const real *prec,
                      __global const real *pcoef, __global const real *tstats, const real margin, const int t,
                      const int m, const int Bcap)
{
    __global const real *r = prec + REC * (t * Bcap + m);
    __global const real *co = pcoef + 3 * (t * Bcap + m);
    const real u = xd - r[R_MD];
    const real diff = u * r[R_DD] - (xt - r[R_MT]) * r[R_DT];
    const real md = FABSG(diff) > margin ? wv * diff : (real)0;  /* wv = 1 without weights: exact */
    return co[0] * md + co[1] * u + co[2] + tstats[4 * t + 2] * (xd - tstats[4 * t + 3]);
}

/* d/dD(i, j) of sum |D[x] - D[x+1]| wx + sum |D[y] - D[y+1]| wy (unnormalised). The sign of a
 * float difference is exact, so this matches the float64 reference up to the weights' rounding. */
static real depth_smooth_grad(__global const float *depth, __global const float *wx,
                              __global const float *wy, const int i, const int j, const int W, const int H)
{
    const int p = j * W + i;
    const float d = depth[p];
    real g = (real)0;
    if (i + 1 < W) g += (real)SIGNF(d - depth[p + 1]) * (real)wx[p];
    if (i > 0) g -= (real)SIGNF(depth[p - 1] - d) * (real)wx[p - 1];
    if (j + 1 < H) g += (real)SIGNF(d - depth[p + W]) * (real)wy[p];
    if (j > 0) g -= (real)SIGNF(depth[p - W] - d) * (real)wy[p - W];
    return g;
}

/* REINGS_CPU_SCHEDULE=1 (PoCL): global (H), one work-item per row, patch indices stepped along the
 * row (no integer division per pixel). Otherwise global (>= W, H), one work-item per pixel. */
__kernel void dl_grad(__global const float *depth,   // [H, W]
                      __global const float *target,  // [H, W]
                      __global const real *prec,     // [2, Bcap, REC]
                      __global const real *pcoef,    // [2, Bcap, 3]
                      __global const real *tstats,   // [2, 4]
                      __global float *v_depth,       // [H, W] dL/d depth (overwritten)
                      const real margin, const real w_local, const real w_global,
                      const int W, const int H, const int pl, const int pg, const int Bcap,
                      __global const float *swx,     // [H, W] smoothness x weights (read if s_scale != 0)
                      __global const float *swy,     // [H, W] smoothness y weights
                      const real s_scale,            // w_smooth / (sum swx + sum swy); 0 = no smoothness
                      __global const float *wt,      // [H, W] per-pixel weights (read if has_wt)
                      const int has_wt)
{
#if REINGS_CPU_SCHEDULE
    const int j = get_global_id(0);
    if (!(j < H)) return;
    const int i0 = 0, i1 = W;
#else
    const int j = get_global_id(1), i0 = get_global_id(0), i1 = i0 + 1;
    if (!(i0 < W && j < H)) return;
#endif
    const real kd = SHIFT(depth), kt = SHIFT(target);
    /* per term: patch columns pw, region width pw * p, row inside the region, first patch of the row */
    const int pw0 = W / pl, pw1 = W / pg;
    const bool in0 = j < (H / pl) * pl && tstats[0] > (real)0;  /* empty mask: no gradient at all */
    const bool in1 = j < (H / pg) * pg && tstats[4] > (real)0;
    const int row0 = (j / pl) * pw0, row1 = (j / pg) * pw1;
    int c0, c1, r0, r1;  /* patch column of pixel i and the position inside it */
    divmod((uint)i0, (uint)pl, &c0, &r0);
    divmod((uint)i0, (uint)pg, &c1, &r1);
    for (int i = i0; i < i1; ++i) {
        const real xd = (real)depth[j * W + i] - kd, xt = (real)target[j * W + i] - kt;
        const real wv = has_wt ? (real)wt[j * W + i] : (real)1;
        const real g0 = (in0 && c0 < pw0) ? term_grad(xd, xt, wv, prec, pcoef, tstats, margin, 0, row0 + c0, Bcap) : (real)0;
        const real g1 = (in1 && c1 < pw1) ? term_grad(xd, xt, wv, prec, pcoef, tstats, margin, 1, row1 + c1, Bcap) : (real)0;
        const real gs = s_scale != (real)0 ? depth_smooth_grad(depth, swx, swy, i, j, W, H) : (real)0;
        v_depth[j * W + i] = (float)(w_local * g0 + w_global * g1 + s_scale * gs);
        if (++r0 == pl) { r0 = 0; ++c0; }
        if (++r1 == pg) { r1 = 0; ++c1; }
    }
}

/* The smoothness loss's numerator per row (launched only when the host reads the loss):
 * rows[j] = sum_i |D[j, i] - D[j, i+1]| wx[j, i] + |D[j, i] - D[j+1, i]| wy[j, i], in real; the
 * host sums the rows in order and divides by sum wx + sum wy. Global (>= H). */
__kernel void depth_smooth_rows(__global const float *depth, __global const float *swx,
                                __global const float *swy, __global real *rows, const int W, const int H)
{
    const int j = get_global_id(0);
    if (!(j < H)) return;
    real acc = (real)0;
    for (int i = 0; i < W; ++i) {
        const int p = j * W + i;
        const real d = (real)depth[p];
        if (i + 1 < W) acc += FABSG(d - (real)depth[p + 1]) * (real)swx[p];
        if (j + 1 < H) acc += FABSG(d - (real)depth[p + W]) * (real)swy[p];
    }
    rows[j] = acc;
}
