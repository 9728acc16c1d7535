/* bin.cl: tile binning, Brush style (two 32-bit sorts instead of one 64-bit sort).

   Computes the same function as `reings.backends.reference.bin` (index spaces of
   reings/backends/base.py: gid, rank, emit, isect, tile). The pipeline (OpenCLBackend._bin):

     project_fwd   depth_keys[gid] = float bits of t_z where t_z > near, else DEPTH_KEY_CULLED (the
                   near-plane test only: a Gaussian culled for another reason keeps its z key and has
                   an empty tile rect), gid_vals = gid
     sort_pairs    32-bit stable radix sort of all N (depth_key, gid) pairs: the ranked Gaussians (a
                   z key) come first, in (t_z, gid) order (ties keep gid order because the input is
                   in gid order), so sorted values[0:V] = gid_from_rank. The others trail with the
                   sentinel key. The visible Gaussians are a subset of the ranked ones, in the same
                   relative order as a sort of the visible ones alone (a stable sort's order restricted
                   to a subset is the subset's stable order), so one order serves every forward of the
                   same means and camera z row whatever it culls (OpenCLBackend, "Depth orders").
     bin_count     per rank r in [0, N]: tiles_touched[r] (0 for r >= V, and for a ranked Gaussian
                   culled otherwise: its tile rect is empty), ctrl[0] = V (the one r where the ranked
                   prefix ends; no atomics), ctrl[2] += the visible ranks (radii > 0; ctrl[2]
                   zeroed by project_fwd, or by the host for an uploaded projection; one atomic add
                   per block), and the scan's block sums of tiles_touched over the scan's blocks
                   (ExclusiveScan.blocks: the scan's first pass, scan_reduce, is not launched)
     scan          scan_add alone: exclusive scan of tiles_touched[0..N] -> offset_from_rank,
                   offset_from_rank[N] = K: the ranks culled otherwise add nothing, so a visible
                   rank's emit slots are those of the visible-only binning, and K is the same
     (one blocking read of ctrl = (V, K, visible); none in the sync-free mode, below)
     bin_emit      per rank r < V: its tiles row-major (ty outer, tx inner) at emit slots
                   offset_from_rank[r] + i: tile_keys[emit] = tile, emit_vals[emit] = emit,
                   gid_from_emit[emit] = gid (nothing for an empty rect)
     sort_pairs    stable radix sort of (tile_keys, emit_vals) over ceil(log2(T)) bits: depth order is
                   kept inside a tile -> emit_from_isect
     tile_ranges   per isect i in [0, K]: [start, end) of every tile from the sorted keys (searchsorted
                   semantics; each tile written exactly once, no atomics) and gid_from_isect

   Device counts (the sync-free binning, docs/perf_notes.md §8): bin_emit and tile_ranges take
   (counts, count_at) last. count_at < 0: the scalar count (n_ranked, n_isects) is V or K, read
   back by the host. count_at >= 0: V or K is counts[count_at] (ctrl, written by bin_count and the
   scan), the scalar is only a bound; the host launches bin_emit over all N ranks (ranks >= V emit
   nothing) and tile_ranges for an estimate of K + 1 (a grid-stride loop covers 0..K whatever the
   launch size). The buffers are sized for K <= V * n_tiles (every tile rect lies in the grid).

   V here counts the ranked Gaussians (the sort's prefix), the launch bound of bin_emit and the
   reduces; the visible count (radii > 0) is ctrl[2], the statistic reported as "visible".

   Defines: REINGS_CPU_SCHEDULE (bin_count's blocks: a work-item per block on CPUs, a work-group per
   block on GPUs), on the GPU schedule SCAN_WG / SCAN_ITEMS (the scan's block: ExclusiveScan's
   defines), TR_CHUNK (tile_ranges' positions per work-item, the host's `tr_chunk`). The tile grid
   arrives as tiles_x / n_tiles. Integers only: no float math here.
*/

#include "common.h"

#define DEPTH_KEY_CULLED 0xFFFFFFFFu /* project.cl's key of a culled Gaussian: sorts last */

/* The tiles of rank r in [0, N] (0 for r >= V and for an empty rect), its visibility (radii > 0), and
   ctrl[0] = V at the one r where the ranked prefix ends. */
static inline uint rank_tiles(const int r, const int n, __global const uint *depth_keys_sorted,
                              __global const uint *gid_from_rank, __global const int *tile_rect,
                              __global const int *radii, __global uint *ctrl, uint *vis) {
    const bool ranked = r < n && depth_keys_sorted[r] != DEPTH_KEY_CULLED;
    const bool prev_ranked = r == 0 || depth_keys_sorted[r - 1] != DEPTH_KEY_CULLED;
    if (prev_ranked && !ranked) ctrl[0] = (uint)r; /* the ranked Gaussians form a prefix: one writer */
    if (!ranked) return 0u;
    const uint g = gid_from_rank[r];
    __global const int *rc = tile_rect + 4 * (size_t)g;
    *vis += radii[g] > 0;
    return (uint)((rc[2] - rc[0]) * (rc[3] - rc[1]));
}

#if REINGS_CPU_SCHEDULE
/* CPU schedule: a work-item per block of `chunk` ranks (the scan's blocks), serial, no barriers. */
__kernel void bin_count(const int n,
                        __global const uint *depth_keys_sorted, /* [N] */
                        __global const uint *gid_from_rank,     /* [N] (entries >= V are unranked gids) */
                        __global const int *tile_rect,          /* [N, 4] by gid (zeros where culled) */
                        __global const int *radii,              /* [N] by gid (> 0: visible) */
                        __global uint *tiles_touched,           /* [N + 1] */
                        __global uint *ctrl,                    /* [3]: ctrl[0] = V, ctrl[2] += visible */
                        const uint chunk,                       /* ranks per block (ExclusiveScan.blocks) */
                        __global uint *block_sums) {            /* [nblocks]: the scan's block sums */
    const int b = get_global_id(0);
    const int lo = b * (int)chunk, hi = min(n + 1, lo + (int)chunk);
    uint s = 0, vis = 0;
    for (int r = lo; r < hi; ++r) {
        const uint cnt = rank_tiles(r, n, depth_keys_sorted, gid_from_rank, tile_rect, radii, ctrl, &vis);
        tiles_touched[r] = cnt;
        s += cnt;
    }
    block_sums[b] = s;
    if (vis) atomic_add(&ctrl[2], vis);
    if (n == 0 && b == 0) ctrl[2] = 0u; /* no Gaussian: project_fwd launched no work-item to zero it */
}
#else
#ifndef SCAN_WG
#define SCAN_WG 256 /* scan.cl's defaults; the host passes ExclusiveScan's own (sort.py) */
#endif
#ifndef SCAN_ITEMS
#define SCAN_ITEMS 8
#endif
#define WG_SCAN_SIZE SCAN_WG
#include "wg_scan.h"
#define SCAN_BLOCK (SCAN_WG * SCAN_ITEMS)

/* GPU schedule: a work-group of SCAN_WG per block of SCAN_BLOCK ranks (the scan's blocks), coalesced. */
__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void bin_count(const int n,
               __global const uint *depth_keys_sorted, /* [N] */
               __global const uint *gid_from_rank,     /* [N] (entries >= V are unranked gids) */
               __global const int *tile_rect,          /* [N, 4] by gid (zeros where culled) */
               __global const int *radii,              /* [N] by gid (> 0: visible) */
               __global uint *tiles_touched,           /* [N + 1] */
               __global uint *ctrl,                    /* [3]: ctrl[0] = V, ctrl[2] += visible */
               const uint chunk,                       /* unused (block = SCAN_BLOCK) */
               __global uint *block_sums) {            /* [nblocks]: the scan's block sums */
    __local uint tmp[SCAN_WG];
    const int lid = get_local_id(0);
    const int base = get_group_id(0) * SCAN_BLOCK;
    uint s = 0, vis = 0;
    for (int k = 0; k < SCAN_ITEMS; ++k) {
        const int r = base + k * SCAN_WG + lid;
        if (r <= n) {
            const uint cnt = rank_tiles(r, n, depth_keys_sorted, gid_from_rank, tile_rect, radii, ctrl, &vis);
            tiles_touched[r] = cnt;
            s += cnt;
        }
    }
    uint sum, vsum;
    wg_exclusive_scan(s, tmp, &sum);
    wg_exclusive_scan(vis, tmp, &vsum);
    if (lid == 0) {
        block_sums[get_group_id(0)] = sum;
        if (vsum) atomic_add(&ctrl[2], vsum);
        if (n == 0) ctrl[2] = 0u; /* no Gaussian: project_fwd launched no work-item to zero it */
    }
}
#endif

/* Per rank r < V: write its tiles at its emit slots. */
__kernel void bin_emit(const int n_ranked, const int tiles_x,
                       __global const uint *gid_from_rank,    /* [V] */
                       __global const uint *offset_from_rank, /* [V + 1] */
                       __global const int *tile_rect,         /* [N, 4] by gid */
                       __global uint *tile_keys,              /* [K] by emit */
                       __global uint *emit_vals,              /* [K] by emit, = emit */
                       __global uint *gid_from_emit,          /* [K] */
                       __global const uint *counts,           /* V = counts[count_at] (header) */
                       const int count_at) {
    const int r = get_global_id(0);
    if (r >= (int)launch_count((uint)n_ranked, counts, count_at)) return;
    const uint g = gid_from_rank[r];
    __global const int *rc = tile_rect + 4 * (size_t)g;
    const int tx0 = rc[0], ty0 = rc[1], tx1 = rc[2], ty1 = rc[3];
    uint e = offset_from_rank[r];
    /* one loop over the rect's w h tiles, row-major: one loop exit per rank where nested row / column loops
     * had one per row and one more (a rank's rect size is data; bin_emit 0.89x on fern's fine state, session 40) */
    const int w = tx1 - tx0, h = ty1 - ty0;
    const uint cnt = w > 0 && h > 0 ? (uint)(w * h) : 0u;
    int tx = tx0, key = ty0 * tiles_x + tx0;
    for (uint j = 0; j < cnt; ++j, ++e) {
        tile_keys[e] = (uint)key;
        emit_vals[e] = e;
        gid_from_emit[e] = g;
        const int wrap = ++tx == tx1; /* the row's last tile: back to tx0 of the next row */
        tx = wrap ? tx0 : tx;
        key += wrap ? tiles_x - w + 1 : 1;
    }
}

#ifndef TR_CHUNK
#define TR_CHUNK 1
#endif
/* Per sorted intersection i in [0, K]: TR_CHUNK consecutive positions per work-item (the host launches
   ceil((K + 1) / TR_CHUNK); OpenCLBackend.tr_chunk: 32 on CPUs, 0.50-0.61x of one position per work-item on fern's
   fine state, 2 Xeon cores, docs/perf_notes.md §43; 1 on GPUs). Tile t's range is [start, end) with
   start = first i with key >= t, end = first i with key > t (numpy searchsorted left/right), so an
   empty tile gets start == end == the position where it would be. */
__kernel void tile_ranges(const int n_isects, const int n_tiles,
                          __global const uint *tile_keys_sorted, /* [K] */
                          __global const uint *emit_from_isect,  /* [K] */
                          __global const uint *gid_from_emit,    /* [K] */
                          __global int *ranges,                  /* [T, 2] */
                          __global int *gid_from_isect,          /* [K] */
                          __global const uint *counts,           /* K = counts[count_at] (header) */
                          const int count_at) {
    const int k = (int)launch_count((uint)n_isects, counts, count_at);
    /* TR_CHUNK consecutive positions per work-item (CPU schedule), chunk after chunk grid-stride */
    const int stride = (int)get_global_size(0) * TR_CHUNK;
    for (int base = get_global_id(0) * TR_CHUNK; base <= k; base += stride) { /* once with a host count */
        const int last = min(base + TR_CHUNK - 1, k);
        for (int i = base; i <= last; ++i) {
            const int prev = i == 0 ? -1 : (int)tile_keys_sorted[i - 1];
            const int cur = i == k ? n_tiles : (int)tile_keys_sorted[i];
            /* tiles in (prev, cur] start at i; tiles in [prev, cur) end at i */
            for (int t = prev + 1; t <= cur && t < n_tiles; ++t) ranges[2 * t] = i;
            for (int t = max(prev, 0); t < cur; ++t) ranges[2 * t + 1] = i;
            if (i < k) gid_from_isect[i] = (int)gid_from_emit[emit_from_isect[i]];
        }
        if (base > k - stride) break; /* base + stride > k: stop before the int sum can pass INT_MAX */
    }
}
