/* kernels/sort.cl -- LSD radix sort of (key, value) pairs, stable, reduce-then-scan.
 *
 * Sorts keys (uint32, or uint64 with -D KEY64=1) carrying uint32 values by the bits
 * [begin_bit, end_bit) only; equal digits keep their input order (stable), so a second sort on other
 * bits refines the first (a 32-bit depth sort, then a stable 10-bit tile-id sort). The host
 * (reings.backends.opencl.sort.RadixSort) splits the bit range into passes of at most RADIX_BITS
 * bits; one pass sorts by digit = (key >> shift) & (nbins - 1), nbins = 2^pass_bits <= 2^RADIX_BITS.
 *
 * Reference: numpy.argsort(kind="stable") on (key >> begin_bit) & mask (tests/test_sort.py).
 *
 * One pass, reduce-then-scan (never a decoupled look-back: PoCL has no forward-progress guarantee
 * between work-groups, docs/perf_notes.md §4.1):
 *   radix_hist     block b counts its digits -> hist[d * nblocks + b]   (digit-major matrix)
 *   radix_scan     (GPU schedule) work-group d scans row d in place (exclusive, block order) and
 *                  writes the row total to totals[d]
 *   radix_scatter  block b writes each element to
 *                    sum_{d' < d} totals[d'] + hist_scanned[d][b] + (rank of the element among the
 *                    block's elements of digit d, in input order)
 *                  The digit-major order of the scan (all of digit 0 over all blocks, then digit 1,
 *                  ...) together with an in-order rank inside a block makes the pass stable.
 *
 * Schedules (REINGS_CPU_SCHEDULE, passed by the KernelLibrary from quirks.build_defines):
 *   1 (CPU, PoCL): one work-item per block, local size 1, serial loops, no barriers and no atomics.
 *     Few large blocks (the host uses about 4 per core). radix_scatter sums its own offsets out of
 *     the small unscanned hist matrix (nbins * nblocks entries), so radix_scan is not launched and a
 *     pass is two launches.
 *   0 (GPU): one work-group of SORT_WG work-items per block of SORT_WG * SORT_ITEMS elements.
 *     radix_hist: local-memory histogram with local atomic_inc. radix_scatter: the block's
 *     (digit, index) pairs are sorted in local memory by pass_bits stable 1-bit splits (each a
 *     work-group scan), which gives every element its in-order rank within its digit; the global
 *     writes then go out in sorted order (runs of one digit are contiguous, so they coalesce).
 *
 * Defines (defaults in brackets):
 *   KEY64 [0]           1: keys are uint64 (ulong)
 *   RADIX_BITS [8]      widest digit a pass may use (1..16); the histogram has 2^RADIX_BITS bins
 *   REINGS_CPU_SCHEDULE [0]
 *   SORT_WG [256], SORT_ITEMS [8]  GPU schedule: work-group size (power of two) and elements per
 *                       work-item; SORT_WG * SORT_ITEMS <= 65536 (local indices are 16 bits)
 *
 * Not handled here: n == 0 or zero passes (the host skips the launches), n >= 2^32.
 */

#ifndef KEY64
#define KEY64 0
#endif
#ifndef RADIX_BITS
#define RADIX_BITS 8
#endif
#ifndef REINGS_CPU_SCHEDULE
#define REINGS_CPU_SCHEDULE 0
#endif
#ifndef SORT_WG
#define SORT_WG 256
#endif
#ifndef SORT_ITEMS
#define SORT_ITEMS 8
#endif

#define RADIX (1u << RADIX_BITS)
#define SORT_BLOCK (SORT_WG * SORT_ITEMS)

#if KEY64
typedef ulong key_t;
#else
typedef uint key_t;
#endif

inline uint digit_of(const key_t k, const uint shift, const uint nbins)
{
    return (uint)(k >> shift) & (nbins - 1u);
}

#if REINGS_CPU_SCHEDULE

/* ---------------------------------------------------------------- CPU schedule: work-item = block */

__kernel void radix_hist(__global const key_t *keys, // [n]
                         const uint n,
                         const uint chunk,           // elements per block
                         const uint shift,
                         const uint nbins,           // 2^pass_bits
                         __global uint *hist)        // [nbins, nblocks], digit-major
{
    const uint b = get_global_id(0);
    const uint nblocks = get_global_size(0);
    uint h[RADIX];
    for (uint d = 0; d < nbins; ++d) h[d] = 0;
    const uint lo = b * chunk;
    const uint hi = min(n, lo + chunk);
    for (uint i = lo; i < hi; ++i) h[digit_of(keys[i], shift, nbins)]++;
    for (uint d = 0; d < nbins; ++d) hist[d * nblocks + b] = h[d];
}

/* Not launched on the CPU schedule (radix_scatter scans for itself); kept so both schedules export
 * the same kernels. */
__kernel void radix_scan(__global uint *hist,   // [nbins, nblocks]
                         const uint nblocks,
                         const uint nbins,
                         __global uint *totals) // [nbins]
{
}

__kernel void radix_scatter(__global const key_t *keys_in, // [n]
                            __global const uint *vals_in,  // [n]
                            __global key_t *keys_out,      // [n]
                            __global uint *vals_out,       // [n]
                            const uint n,
                            const uint chunk,
                            const uint shift,
                            const uint nbins,
                            __global const uint *hist,     // [nbins, nblocks] from radix_hist
                            __global const uint *totals)   // unused on this schedule
{
    const uint b = get_global_id(0);
    const uint nblocks = get_global_size(0);
    uint off[RADIX];
    uint run = 0;
    for (uint d = 0; d < nbins; ++d) {
        __global const uint *row = hist + d * nblocks;
        uint before = 0;
        for (uint j = 0; j < b; ++j) before += row[j];
        uint all = before;
        for (uint j = b; j < nblocks; ++j) all += row[j];
        off[d] = run + before;
        run += all;
    }
    const uint lo = b * chunk;
    const uint hi = min(n, lo + chunk);
    for (uint i = lo; i < hi; ++i) {
        const key_t k = keys_in[i];
        const uint p = off[digit_of(k, shift, nbins)]++;
        keys_out[p] = k;
        vals_out[p] = vals_in[i];
    }
}

#else

/* ------------------------------------------------------- GPU schedule: work-group = block */

#define WG_SCAN_SIZE SORT_WG
#include "wg_scan.h"

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_hist(__global const key_t *keys, // [n]
                const uint n,
                const uint chunk,           // unused (block = SORT_BLOCK)
                const uint shift,
                const uint nbins,
                __global uint *hist)        // [nbins, nblocks], digit-major
{
    __local uint h[RADIX];
    const uint lid = get_local_id(0);
    const uint g = get_group_id(0);
    const uint nblocks = get_num_groups(0);
    for (uint d = lid; d < nbins; d += SORT_WG) h[d] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint base = g * SORT_BLOCK;
    for (uint k = 0; k < SORT_ITEMS; ++k) { /* coalesced */
        const uint i = base + k * SORT_WG + lid;
        if (i < n) atomic_inc(&h[digit_of(keys[i], shift, nbins)]);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint d = lid; d < nbins; d += SORT_WG) hist[d * nblocks + g] = h[d];
}

/* Work-group d: hist[d, 0..nblocks) -> exclusive prefix in place; totals[d] = row sum. */
__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_scan(__global uint *hist,   // [nbins, nblocks]
                const uint nblocks,
                const uint nbins,
                __global uint *totals) // [nbins]
{
    __local uint tmp[SORT_WG];
    const uint lid = get_local_id(0);
    __global uint *row = hist + get_group_id(0) * nblocks;
    uint carry = 0;
    for (uint c = 0; c < nblocks; c += SORT_WG) {
        const uint i = c + lid;
        const uint x = i < nblocks ? row[i] : 0u;
        uint sum;
        const uint ex = wg_exclusive_scan(x, tmp, &sum);
        if (i < nblocks) row[i] = carry + ex;
        carry += sum;
    }
    if (lid == 0) totals[get_group_id(0)] = carry;
}

#define DIGITS_PER_ITEM ((RADIX + SORT_WG - 1) / SORT_WG)

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_scatter(__global const key_t *keys_in, // [n]
                   __global const uint *vals_in,  // [n]
                   __global key_t *keys_out,      // [n]
                   __global uint *vals_out,       // [n]
                   const uint n,
                   const uint chunk,              // unused
                   const uint shift,
                   const uint nbins,
                   __global const uint *hist,     // [nbins, nblocks] scanned by radix_scan
                   __global const uint *totals)   // [nbins] row totals from radix_scan
{
    __local uint ent[2][SORT_BLOCK]; /* (digit << 16) | local index */
    __local uint tmp[SORT_WG];
    __local uint dbase[RADIX];       /* global position of the block's first element of digit d */
    __local uint dstart[RADIX];      /* local position of the first element of digit d after the split */
    const uint lid = get_local_id(0);
    const uint g = get_group_id(0);
    const uint nblocks = get_num_groups(0);
    const uint base = g * SORT_BLOCK;
    const uint count = min((uint)SORT_BLOCK, n - base); /* valid elements of this block */

    /* 1. digits of the SORT_ITEMS consecutive elements this work-item owns; the padding past n gets
     *    the largest digit, so the stable splits put it after every valid element. */
    for (uint k = 0; k < SORT_ITEMS; ++k) {
        const uint p = lid * SORT_ITEMS + k;
        const uint d = p < count ? digit_of(keys_in[base + p], shift, nbins) : nbins - 1u;
        ent[0][p] = (d << 16) | p;
    }

    /* 2. dbase[d] = sum_{d' < d} totals[d'] + hist[d][g]; each work-item owns DIGITS_PER_ITEM digits. */
    {
        uint s = 0;
        for (uint j = 0; j < DIGITS_PER_ITEM; ++j) {
            const uint d = lid * DIGITS_PER_ITEM + j;
            if (d < nbins) s += totals[d];
        }
        uint sum;
        uint acc = wg_exclusive_scan(s, tmp, &sum); /* its barriers also publish ent[0] */
        for (uint j = 0; j < DIGITS_PER_ITEM; ++j) {
            const uint d = lid * DIGITS_PER_ITEM + j;
            if (d < nbins) {
                dbase[d] = acc + hist[d * nblocks + g];
                acc += totals[d];
            }
        }
    }

    /* 3. stable local sort of the block by digit: one 1-bit split per digit bit, LSB first. */
    uint cur = 0;
    for (uint bit = 16; (1u << (bit - 16)) < nbins; ++bit) {
        __local const uint *src = ent[cur];
        __local uint *dst = ent[cur ^ 1u];
        uint zeros = 0;
        for (uint k = 0; k < SORT_ITEMS; ++k) zeros += ((src[lid * SORT_ITEMS + k] >> bit) & 1u) ^ 1u;
        uint nz;
        uint zp = wg_exclusive_scan(zeros, tmp, &nz);
        uint op = nz + lid * SORT_ITEMS - zp;
        for (uint k = 0; k < SORT_ITEMS; ++k) {
            const uint e = src[lid * SORT_ITEMS + k];
            if ((e >> bit) & 1u) dst[op++] = e;
            else dst[zp++] = e;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        cur ^= 1u;
    }
    __local const uint *srt = ent[cur];

    /* 4. where each digit's run starts in the sorted block (only present digits are written/read) */
    for (uint p = lid; p < count; p += SORT_WG) {
        const uint d = srt[p] >> 16;
        if (p == 0 || (srt[p - 1] >> 16) != d) dstart[d] = p;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* 5. scatter in sorted order: p runs over the block, consecutive work-items take consecutive p */
    for (uint p = lid; p < count; p += SORT_WG) {
        const uint e = srt[p];
        const uint d = e >> 16;
        const uint src_i = base + (e & 0xFFFFu);
        const uint dst_i = dbase[d] + (p - dstart[d]);
        keys_out[dst_i] = keys_in[src_i];
        vals_out[dst_i] = vals_in[src_i];
    }
}

#endif
