/* kernels/scan.cl -- exclusive prefix sum of uint32 (reduce-then-scan).
 *
 *   out[i] = in[0] + ... + in[i-1]   (mod 2^32),   total = in[0] + ... + in[n-1]
 *
 * Reference: numpy.cumsum (tests/test_sort.py). Host side: reings.backends.opencl.sort.ExclusiveScan.
 *
 * Reduce-then-scan, never a decoupled look-back: PoCL gives no forward-progress guarantee between
 * work-groups (docs/perf_notes.md §4.1), so no work-group ever waits on another one inside a launch.
 *
 *   scan_reduce  block b -> block_sums[b] = sum of its elements (bin.cl's bin_count writes the same
 *                sums for the binning's tile counts, so a forward scans them with scan_add alone)
 *   scan_add     block b sums the block sums before it (its offset), scans its elements and adds
 *                the offset; the last block writes the grand total. in == out is allowed. Two
 *                launches on both schedules (a third, a one-work-group scan of the block sums,
 *                cost a launch per scan on GPUs until 2026-11-27: blocks are few, ~N / 2048, so
 *                each work-group reading the sums before it is cheap).
 *
 * Defines (defaults in brackets):
 *   REINGS_CPU_SCHEDULE [0]  1: one work-item per block, serial loops, no barriers, local size 1
 *                            (PoCL runs a work-group as a loop over its work-items; barriers cost).
 *                            0: one work-group of SCAN_WG work-items per block of SCAN_WG*SCAN_ITEMS
 *                            elements, a local-memory scan.
 *   SCAN_WG [256], SCAN_ITEMS [8]  GPU schedule: work-group size (a power of two) and the elements
 *                            each work-item owns (consecutive).
 *
 * Blocks: CPU schedule: the host chooses `chunk` (elements per work-item); GPU schedule: a block is
 * SCAN_WG*SCAN_ITEMS elements. n may be anything, including not a multiple of the block; n == 0 is
 * handled on the host (no launch). Not handled: n >= 2^32.
 */

#ifndef REINGS_CPU_SCHEDULE
#define REINGS_CPU_SCHEDULE 0
#endif
#ifndef SCAN_WG
#define SCAN_WG 256
#endif
#ifndef SCAN_ITEMS
#define SCAN_ITEMS 8
#endif
#define SCAN_BLOCK (SCAN_WG * SCAN_ITEMS)

#if REINGS_CPU_SCHEDULE

/* ---------------------------------------------------------------- CPU schedule: work-item = block */

__kernel void scan_reduce(__global const uint *in,   // [n]
                          const uint n,
                          const uint chunk,          // elements per block
                          __global uint *block_sums) // [nblocks]
{
    const uint b = get_global_id(0);
    const uint lo = b * chunk;
    const uint hi = min(n, lo + chunk);
    uint s = 0;
    for (uint i = lo; i < hi; ++i) s += in[i];
    block_sums[b] = s;
}

__kernel void scan_add(__global const uint *in,         // [n]  (may alias out)
                       __global uint *out,              // [n]
                       const uint n,
                       const uint chunk,
                       __global const uint *block_sums, // [nblocks] from scan_reduce (not scanned)
                       __global uint *total,            // [>= total_at + 1] grand total written here
                       const uint total_at)
{
    const uint b = get_global_id(0);
    const uint nblocks = get_global_size(0);
    uint acc = 0;
    for (uint j = 0; j < b; ++j) acc += block_sums[j];
    const uint lo = b * chunk;
    const uint hi = min(n, lo + chunk);
    for (uint i = lo; i < hi; ++i) {
        const uint x = in[i];
        out[i] = acc;
        acc += x;
    }
    if (b == nblocks - 1) total[total_at] = acc;
}

#else

/* ------------------------------------------------------- GPU schedule: work-group = block */

#define WG_SCAN_SIZE SCAN_WG
#include "wg_scan.h"

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_reduce(__global const uint *in,   // [n]
                 const uint n,
                 const uint chunk,          // unused (block = SCAN_BLOCK)
                 __global uint *block_sums) // [nblocks]
{
    __local uint tmp[SCAN_WG];
    const uint lid = get_local_id(0);
    const uint base = get_group_id(0) * SCAN_BLOCK;
    uint s = 0;
    for (uint k = 0; k < SCAN_ITEMS; ++k) { /* coalesced: consecutive work-items, consecutive i */
        const uint i = base + k * SCAN_WG + lid;
        if (i < n) s += in[i];
    }
    uint sum;
    wg_exclusive_scan(s, tmp, &sum);
    if (lid == 0) block_sums[get_group_id(0)] = sum;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_add(__global const uint *in,         // [n]  (may alias out)
              __global uint *out,              // [n]
              const uint n,
              const uint chunk,                // unused (block = SCAN_BLOCK)
              __global const uint *block_sums, // [nblocks] from scan_reduce (not scanned)
              __global uint *total,            // [>= total_at + 1] grand total written here
              const uint total_at)
{
    __local uint tmp[SCAN_WG];
    const uint lid = get_local_id(0);
    const uint b = get_group_id(0);
    /* this block's offset: the sum of the block sums before it, over the work-group */
    uint part = 0;
    for (uint j = lid; j < b; j += SCAN_WG) part += block_sums[j];
    uint offset;
    wg_exclusive_scan(part, tmp, &offset);
    const uint base = b * SCAN_BLOCK + lid * SCAN_ITEMS; /* SCAN_ITEMS consecutive */
    uint x[SCAN_ITEMS];
    uint s = 0;
    for (uint k = 0; k < SCAN_ITEMS; ++k) {
        const uint i = base + k;
        x[k] = i < n ? in[i] : 0u;
        s += x[k];
    }
    uint sum;
    uint acc = wg_exclusive_scan(s, tmp, &sum) + offset;
    for (uint k = 0; k < SCAN_ITEMS; ++k) {
        const uint i = base + k;
        if (i < n) out[i] = acc;
        acc += x[k];
    }
    if (lid == 0 && b == get_num_groups(0) - 1) total[total_at] = offset + sum;
}

#endif
