/* kernels/scan.cl -- exclusive prefix sum of uint32 (reduce-then-scan).
 *
 *   out[i] = in[0] + ... + in[i-1]   (mod 2^32),   total = in[0] + ... + in[n-1]
 *
 * Reference: numpy.cumsum (tests/test_sort.py). Host side: reings.backends.opencl.sort.ExclusiveScan.
 *
 * Reduce-then-scan, never a decoupled look-back: PoCL gives no forward-progress guarantee between
 * work-groups (docs/perf_notes.md §4.1), so no work-group ever waits on another one inside a launch.
 *
 *   scan_reduce  block b -> block_sums[b] = sum of its elements
 *   scan_top     (GPU schedule only) one work-group scans block_sums[0..nblocks) in place, exclusive,
 *                and writes the grand total
 *   scan_add     block b scans its elements and adds its block offset; in == out is allowed.
 *                CPU schedule: the block offset is summed from block_sums here (nblocks is small),
 *                and the last block writes the total, so the CPU path is two launches.
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

/* scan_top is not needed on the CPU schedule; a stub keeps the kernel list identical. */
__kernel void scan_top(__global uint *block_sums, // [nblocks]
                       const uint nblocks,
                       __global uint *total,      // unused
                       const uint total_at)
{
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

/* One work-group: block_sums[0..nblocks) -> exclusive prefix in place, total[total_at] = sum. */
__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_top(__global uint *block_sums, // [nblocks]
              const uint nblocks,
              __global uint *total,      // [>= total_at + 1]
              const uint total_at)
{
    __local uint tmp[SCAN_WG];
    const uint lid = get_local_id(0);
    uint carry = 0;
    for (uint c = 0; c < nblocks; c += SCAN_WG) {
        const uint i = c + lid;
        const uint x = i < nblocks ? block_sums[i] : 0u;
        uint sum;
        const uint ex = wg_exclusive_scan(x, tmp, &sum);
        if (i < nblocks) block_sums[i] = carry + ex;
        carry += sum;
    }
    if (lid == 0) total[total_at] = carry;
}

__kernel __attribute__((reqd_work_group_size(SCAN_WG, 1, 1)))
void scan_add(__global const uint *in,         // [n]  (may alias out)
              __global uint *out,              // [n]
              const uint n,
              const uint chunk,                // unused
              __global const uint *block_sums, // [nblocks] exclusive block offsets from scan_top
              __global uint *total,            // unused here (scan_top wrote it)
              const uint total_at)
{
    __local uint tmp[SCAN_WG];
    const uint lid = get_local_id(0);
    const uint base = get_group_id(0) * SCAN_BLOCK + lid * SCAN_ITEMS; /* SCAN_ITEMS consecutive */
    uint x[SCAN_ITEMS];
    uint s = 0;
    for (uint k = 0; k < SCAN_ITEMS; ++k) {
        const uint i = base + k;
        x[k] = i < n ? in[i] : 0u;
        s += x[k];
    }
    uint sum;
    uint acc = wg_exclusive_scan(s, tmp, &sum) + block_sums[get_group_id(0)];
    for (uint k = 0; k < SCAN_ITEMS; ++k) {
        const uint i = base + k;
        if (i < n) out[i] = acc;
        acc += x[k];
    }
}

#endif
