/* bin.cl: tile binning, Brush style (two 32-bit sorts instead of one 64-bit sort).

   Computes the same function as `reings.backends.reference.bin` (index spaces of
   reings/backends/base.py: gid, rank, emit, isect, tile). The pipeline (OpenCLBackend._bin):

     project_fwd   depth_keys[gid] = float bits of t_z (visible) or DEPTH_KEY_CULLED, gid_vals = gid
     sort_pairs    32-bit stable radix sort of all N (depth_key, gid) pairs: the visible Gaussians come
                   first, in (t_z, gid) order (ties keep gid order because the input is in gid order),
                   so sorted values[0:V] = gid_from_rank. The culled ones trail with the sentinel key.
     bin_count     per rank r in [0, N]: tiles_touched[r] (0 for culled and for r == N), and ctrl[0] = V
                   (the one r where the visible prefix ends; no atomics)
     scan          exclusive scan of tiles_touched[0..N] -> offset_from_rank, offset_from_rank[N] = K
     (one blocking read of ctrl = (V, K); none in the sync-free mode, below)
     bin_emit      per rank r < V: its tiles row-major (ty outer, tx inner) at emit slots
                   offset_from_rank[r] + i: tile_keys[emit] = tile, emit_vals[emit] = emit,
                   gid_from_emit[emit] = gid
     sort_pairs    stable radix sort of (tile_keys, emit_vals) over ceil(log2(T)) bits: depth order is
                   kept inside a tile -> emit_from_isect
     tile_ranges   per isect i in [0, K]: [start, end) of every tile from the sorted keys (searchsorted
                   semantics; each tile written exactly once, no atomics) and gid_from_isect

   Device counts (the sync-free binning, docs/perf_notes.md §8): bin_emit and tile_ranges take
   (counts, count_at) last. count_at < 0: the scalar count (n_visible, n_isects) is V or K, read
   back by the host. count_at >= 0: V or K is counts[count_at] (ctrl, written by bin_count and the
   scan), the scalar is only a bound; the host launches bin_emit over all N ranks (ranks >= V emit
   nothing) and tile_ranges for an estimate of K + 1 (a grid-stride loop covers 0..K whatever the
   launch size). The buffers are sized for K <= V * n_tiles (every tile rect lies in the grid).

   Defines: none (the tile grid arrives as tiles_x / n_tiles). Integers only: no float math here.
*/

#include "common.h"

#define DEPTH_KEY_CULLED 0xFFFFFFFFu /* project.cl's key of a culled Gaussian: sorts last */

/* Per rank r in [0, N] (N + 1 work-items): tiles touched by the Gaussian of rank r, and V. */
__kernel void bin_count(const int n,
                        __global const uint *depth_keys_sorted, /* [N] */
                        __global const uint *gid_from_rank,     /* [N] (entries >= V are culled gids) */
                        __global const int *tile_rect,          /* [N, 4] by gid */
                        __global uint *tiles_touched,           /* [N + 1] */
                        __global uint *ctrl) {                  /* [2]: ctrl[0] = V */
    const int r = get_global_id(0);
    if (r > n) return;
    const bool vis = r < n && depth_keys_sorted[r] != DEPTH_KEY_CULLED;
    const bool prev_vis = r == 0 || depth_keys_sorted[r - 1] != DEPTH_KEY_CULLED;
    if (prev_vis && !vis) ctrl[0] = (uint)r;  /* the visible Gaussians form a prefix: one writer */
    uint cnt = 0;
    if (vis) {
        __global const int *rc = tile_rect + 4 * (size_t)gid_from_rank[r];
        cnt = (uint)((rc[2] - rc[0]) * (rc[3] - rc[1]));
    }
    tiles_touched[r] = cnt;
}

/* Per rank r < V: write its tiles at its emit slots. */
__kernel void bin_emit(const int n_visible, const int tiles_x,
                       __global const uint *gid_from_rank,    /* [V] */
                       __global const uint *offset_from_rank, /* [V + 1] */
                       __global const int *tile_rect,         /* [N, 4] by gid */
                       __global uint *tile_keys,              /* [K] by emit */
                       __global uint *emit_vals,              /* [K] by emit, = emit */
                       __global uint *gid_from_emit,          /* [K] */
                       __global const uint *counts,           /* V = counts[count_at] (header) */
                       const int count_at) {
    const int r = get_global_id(0);
    if (r >= (int)launch_count((uint)n_visible, counts, count_at)) return;
    const uint g = gid_from_rank[r];
    __global const int *rc = tile_rect + 4 * (size_t)g;
    const int tx0 = rc[0], ty0 = rc[1], tx1 = rc[2], ty1 = rc[3];
    uint e = offset_from_rank[r];
    for (int ty = ty0; ty < ty1; ++ty) {
        for (int tx = tx0; tx < tx1; ++tx) {
            tile_keys[e] = (uint)(ty * tiles_x + tx);
            emit_vals[e] = e;
            gid_from_emit[e] = g;
            ++e;
        }
    }
}

/* Per sorted intersection i in [0, K] (K + 1 work-items). Tile t's range is [start, end) with
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
    const int stride = (int)get_global_size(0);
    for (int i = get_global_id(0); i <= k; i += stride) { /* once per work-item with a host count */
        const int prev = i == 0 ? -1 : (int)tile_keys_sorted[i - 1];
        const int cur = i == k ? n_tiles : (int)tile_keys_sorted[i];
        /* tiles in (prev, cur] start at i; tiles in [prev, cur) end at i */
        for (int t = prev + 1; t <= cur && t < n_tiles; ++t) ranges[2 * t] = i;
        for (int t = max(prev, 0); t < cur; ++t) ranges[2 * t + 1] = i;
        if (i < k) gid_from_isect[i] = (int)gid_from_emit[emit_from_isect[i]];
        if (i > k - stride) break; /* i + stride > k: stop before the int sum can pass INT_MAX */
    }
}
