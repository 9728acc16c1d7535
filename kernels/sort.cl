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
 * Device counts (the sync-free binning, docs/perf_notes.md §8): every kernel takes
 * (counts, count_at) after its own arguments. count_at < 0: `n` is the element count (the host knows
 * it). count_at >= 0: the count is counts[count_at], written on the device by an earlier command,
 * and `n` is only the buffers' capacity; the launch size then comes from the host's estimate of the
 * count and need not match it:
 *   CPU schedule: the G launched work-items split [0, count) into G chunks of ceil(count / G)
 *     (`chunk` is computed in the kernel; trailing blocks may be empty).
 *   GPU schedule: the count has nvb = ceil(count / SORT_BLOCK) virtual blocks; work-group g
 *     processes virtual blocks g, g + G, g + 2G, ... (G = work-groups launched, any number >= 1),
 *     the histogram is laid out per virtual block (hist[d * nvb + vb], sized by the host for the
 *     capacity) and radix_scan scans the nvb columns that exist for the count.
 *   With a host count the host launches exactly one block (CPU) / virtual block (GPU) per
 *   work-item / work-group, so every loop runs once and the kernels are the plain ones. A stable
 *   sort's output is unique, so both give the same bits.
 *
 * Defines (defaults in brackets):
 *   KEY64 [0]           1: keys are uint64 (ulong)
 *   RADIX_BITS [8]      widest digit a pass may use (1..16); the histogram has 2^RADIX_BITS bins
 *   REINGS_CPU_SCHEDULE [0]
 *   SORT_WG [256], SORT_ITEMS [8]  GPU schedule: work-group size (power of two) and elements per
 *                       work-item; SORT_WG * SORT_ITEMS <= 65536 (local indices are 16 bits)
 *
 * Not handled here: zero passes (the host skips the launches), n >= 2^32. A host count n <= 1 is
 * skipped by the host; a device count of 0 or 1 is sorted like any other.
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

#include "common.h"

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

/* Elements per block: the host's `chunk`, or with a device count ceil(count / nblocks) (counts
 * stay below 2^31, so the sum cannot wrap; one division: a division paired with its remainder
 * becomes an LLVM `freeze` that Oclgrind's uninitialized-value check cannot run). */
inline uint cpu_chunk(const uint count, const uint chunk, const int count_at, const uint nblocks)
{
    return count_at < 0 ? chunk : (count + nblocks - 1u) / nblocks;
}

__kernel void radix_hist(__global const key_t *keys, // [n]
                         const uint n,
                         const uint chunk,           // elements per block (host count)
                         const uint shift,
                         const uint nbins,           // 2^pass_bits
                         __global uint *hist,        // [nbins, nblocks], digit-major
                         __global const uint *counts, // device count counts[count_at] (header)
                         const int count_at)
{
    const uint b = get_global_id(0);
    const uint nblocks = get_global_size(0);
    const uint count = launch_count(n, counts, count_at);
    const uint ch = cpu_chunk(count, chunk, count_at, nblocks);
    uint h[RADIX];
    for (uint d = 0; d < nbins; ++d) h[d] = 0;
    const uint lo = min(count, b * ch);
    const uint hi = min(count, lo + ch);
    for (uint i = lo; i < hi; ++i) h[digit_of(keys[i], shift, nbins)]++;
    for (uint d = 0; d < nbins; ++d) hist[d * nblocks + b] = h[d];
}

/* Not launched on the CPU schedule (radix_scatter scans for itself); kept so both schedules export
 * the same kernels. */
__kernel void radix_scan(__global uint *hist,   // [nbins, nblocks]
                         const uint n,
                         const uint nbins,
                         __global uint *totals, // [nbins]
                         __global const uint *counts,
                         const int count_at)
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
                            __global const uint *totals,   // unused on this schedule
                            __global const uint *counts,
                            const int count_at)
{
    const uint b = get_global_id(0);
    const uint nblocks = get_global_size(0);
    const uint count = launch_count(n, counts, count_at);
    const uint ch = cpu_chunk(count, chunk, count_at, nblocks);
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
    const uint lo = min(count, b * ch);
    const uint hi = min(count, lo + ch);
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

/* Virtual blocks of a count (GPU schedule): ceil(count / SORT_BLOCK) (count < 2^31: no wrap). */
inline uint virtual_blocks(const uint count)
{
    return (count + (SORT_BLOCK - 1u)) / SORT_BLOCK;
}

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_hist(__global const key_t *keys, // [n]
                const uint n,
                const uint chunk,           // unused (block = SORT_BLOCK)
                const uint shift,
                const uint nbins,
                __global uint *hist,        // [nbins, nvb], digit-major, a column per virtual block
                __global const uint *counts, // device count counts[count_at] (header)
                const int count_at)
{
    __local uint h[RADIX];
    const uint lid = get_local_id(0);
    const uint count = launch_count(n, counts, count_at);
    const uint nvb = virtual_blocks(count);
    for (uint vb = get_group_id(0); vb < nvb; vb += get_num_groups(0)) {
        for (uint d = lid; d < nbins; d += SORT_WG) h[d] = 0;
        barrier(CLK_LOCAL_MEM_FENCE);
        const uint base = vb * SORT_BLOCK;
        for (uint k = 0; k < SORT_ITEMS; ++k) { /* coalesced */
            const uint i = base + k * SORT_WG + lid;
            if (i < count) atomic_inc(&h[digit_of(keys[i], shift, nbins)]);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (uint d = lid; d < nbins; d += SORT_WG) hist[d * nvb + vb] = h[d];
        barrier(CLK_LOCAL_MEM_FENCE); /* h is zeroed again for the next virtual block */
    }
}

/* Work-group d: hist[d, 0..nvb) -> exclusive prefix in place; totals[d] = row sum. */
__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_scan(__global uint *hist,   // [nbins, nvb]
                const uint n,
                const uint nbins,
                __global uint *totals, // [nbins]
                __global const uint *counts,
                const int count_at)
{
    __local uint tmp[SORT_WG];
    const uint lid = get_local_id(0);
    const uint nvb = virtual_blocks(launch_count(n, counts, count_at));
    __global uint *row = hist + get_group_id(0) * nvb;
    uint carry = 0;
    for (uint c = 0; c < nvb; c += SORT_WG) {
        const uint i = c + lid;
        const uint x = i < nvb ? row[i] : 0u;
        uint sum;
        const uint ex = wg_exclusive_scan(x, tmp, &sum);
        if (i < nvb) row[i] = carry + ex;
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
                   __global const uint *hist,     // [nbins, nvb] scanned by radix_scan
                   __global const uint *totals,   // [nbins] row totals from radix_scan
                   __global const uint *counts,
                   const int count_at)
{
    __local uint ent[2][SORT_BLOCK]; /* (digit << 16) | local index */
    __local uint tmp[SORT_WG];
    __local uint dbase[RADIX];       /* global position of the block's first element of digit d */
    __local uint dstart[RADIX];      /* local position of the first element of digit d after the split */
    const uint lid = get_local_id(0);
    const uint n_all = launch_count(n, counts, count_at);
    const uint nvb = virtual_blocks(n_all);
    for (uint vb = get_group_id(0); vb < nvb; vb += get_num_groups(0)) {
        const uint base = vb * SORT_BLOCK;
        const uint count = min((uint)SORT_BLOCK, n_all - base); /* valid elements of this block */

        /* 1. digits of the SORT_ITEMS consecutive elements this work-item owns; the padding past the
         *    count gets the largest digit, so the stable splits put it after every valid element. */
        for (uint k = 0; k < SORT_ITEMS; ++k) {
            const uint p = lid * SORT_ITEMS + k;
            const uint d = p < count ? digit_of(keys_in[base + p], shift, nbins) : nbins - 1u;
            ent[0][p] = (d << 16) | p;
        }

        /* 2. dbase[d] = sum_{d' < d} totals[d'] + hist[d][vb]; each work-item owns DIGITS_PER_ITEM digits. */
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
                    dbase[d] = acc + hist[d * nvb + vb];
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
        barrier(CLK_LOCAL_MEM_FENCE); /* ent, dbase and dstart are rewritten for the next virtual block */
    }
}

#endif
