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
 * One pass, reduce-then-scan (no work-group waits on another; the GPU schedule's host-count sorts take
 * the onesweep kernels at the end of this file instead, docs/perf_notes.md §20):
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

/* Stable local sort of a block's SORT_BLOCK entries ((digit << 16) | local index, in a[]) by digit: one
 * 1-bit split per digit bit, LSB first, between a[] and b[]; returns the sorted one. Every work-item of
 * the group calls it (barriers). radix_scatter's step 3 and radix_onesweep's. */
inline __local const uint *block_sort(__local uint *a, __local uint *b, __local uint *tmp, const uint lid,
                                      const uint nbins)
{
    uint cur = 0;
    for (uint bit = 16; (1u << (bit - 16)) < nbins; ++bit) {
        __local const uint *src = cur ? b : a;
        __local uint *dst = cur ? a : b;
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
    return cur ? b : a;
}

/* The scatter of a sorted block (srt, `count` valid entries of the block at `base`): dstart[d], where
 * digit d's run starts in srt (only the present digits are written and read), then each entry's key
 * and value to dbase[d] + (its position - dstart[d]), consecutive work-items taking consecutive
 * positions. Every work-item of the group calls it (a barrier). radix_scatter's steps 4-5 and
 * radix_onesweep's 5-6. */
inline void block_scatter(__local const uint *srt, __local uint *dstart, __local const uint *dbase,
                          const uint count, const uint base, const uint lid,
                          __global const key_t *keys_in, __global const uint *vals_in,
                          __global key_t *keys_out, __global uint *vals_out)
{
    for (uint p = lid; p < count; p += SORT_WG) {
        const uint d = srt[p] >> 16;
        if (p == 0 || (srt[p - 1] >> 16) != d) dstart[d] = p;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint p = lid; p < count; p += SORT_WG) {
        const uint e = srt[p];
        const uint d = e >> 16;
        const uint src_i = base + (e & 0xFFFFu);
        const uint dst_i = dbase[d] + (p - dstart[d]);
        keys_out[dst_i] = keys_in[src_i];
        vals_out[dst_i] = vals_in[src_i];
    }
}

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

        /* 3. stable local sort of the block by digit (block_sort) */
        __local const uint *srt = block_sort(ent[0], ent[1], tmp, lid, nbins);

        /* 4. where each digit's run starts in the sorted block; 5. the scatter in sorted order (block_scatter) */
        block_scatter(srt, dstart, dbase, count, base, lid, keys_in, vals_in, keys_out, vals_out);
        barrier(CLK_LOCAL_MEM_FENCE); /* ent, dbase and dstart are rewritten for the next virtual block */
    }
}

/* ------------------------------------- GPU schedule, host count: a pass in one launch (onesweep)
 *
 * radix_hist + radix_scan + radix_scatter are three launches per pass; on a GPU run bound by the
 * host's enqueues (docs/perf_notes.md §18-§20) every launch costs ~25-30 us of host time. With a host
 * count the sort instead takes 1 + passes launches (after Adinets and Merrill, "Onesweep: a faster
 * least significant digit radix sort for GPUs", 2022, arXiv:2206.01784):
 *   radix_global_hist  every pass's digit counts over all n keys at once (order-independent):
 *                      ghist[p * RADIX + d]; also zeroes the passes' status words and block-id
 *                      counters, and the other ghist buffer for the next sort (the host alternates
 *                      two: a buffer must be zero when its radix_global_hist starts, and no kernel
 *                      can zero what its own other work-groups are still adding into)
 *   radix_onesweep     one launch per pass: work-group = a block of SORT_BLOCK keys, its block id
 *                      taken from an atomic counter in launch order (so every lower id belongs to a
 *                      work-group that already runs: the waits below always end), its digits'
 *                      counts published at once (AGGREGATE), then the local stable sort as in
 *                      radix_scatter, then per digit a decoupled look-back over the lower blocks'
 *                      words (summing AGGREGATEs until a PREFIX), its own inclusive PREFIX published,
 *                      and the scatter. A status word is (flag << 30) | count in one uint, so a
 *                      relaxed atomic read sees a flag and its count together (n < 2^30, the host
 *                      checks).
 * The element's position is sum_{d' < d} ghist[d'] + (elements of digit d in lower blocks) + (its
 * rank in its block): radix_scatter's position, so the bits are the same (a stable sort is unique).
 * Status: [npass, nvb, stride] words (stride = 2^widest pass), zero before the pass.
 */
#define OS_EMPTY 0u
#define OS_AGGREGATE 1u
#define OS_PREFIX 2u
#define OS_SHIFT 30
#define OS_MASK ((1u << OS_SHIFT) - 1u)
#ifndef OS_WINDOW
#define OS_WINDOW 8 /* status words of lower blocks read at once (independent loads) per look-back step */
#endif
/* Status words are read and written as volatile 32-bit words (one aligned word: its flag and count are
 * seen together; volatile keeps every read of the look-back's wait a fresh load), where the host allows it
 * (quirks.volatile_status_words: NVIDIA, PoCL). OS_ATOMIC_STATUS=1 makes them atomic_or / atomic_xchg,
 * the portable form (Oclgrind, other vendors; on an H100 1.2-3.5x slower at 11-bit digits, docs/perf_notes.md
 * §20). */
#ifndef OS_ATOMIC_STATUS
#define OS_ATOMIC_STATUS 0
#endif
#if OS_ATOMIC_STATUS
#define OS_LOAD(p) atomic_or((p), 0u)
#define OS_STORE(p, v) atomic_xchg((p), (v))
#else
#define OS_LOAD(p) (*(volatile __global uint *)(p))
#define OS_STORE(p, v) (*(volatile __global uint *)(p) = (v))
#endif

/* split_bits' digit width of pass i of npass over `total` bits (reings/backends/opencl/sort.py). */
inline uint pass_width(const uint total, const uint npass, const uint i)
{
    return total / npass + (i < total % npass ? 1u : 0u);
}

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_global_hist(__global const key_t *keys, // [n]
                       const uint n,
                       const uint begin_bit,
                       const uint end_bit,
                       const uint npass,
                       __global uint *ghist,       // [npass, RADIX], zero on entry
                       __global uint *ghist_next,  // [ghist_words]: zeroed for the next sort
                       const uint ghist_words,
                       __global uint *status,      // [status_words]: zeroed
                       const uint status_words,
                       __global uint *ids)         // [npass]: zeroed
{
    __local uint h[RADIX];
    const uint lid = get_local_id(0);
    const uint gid = get_global_id(0), gsz = get_global_size(0);
    for (uint i = gid; i < status_words; i += gsz) status[i] = 0u;
    for (uint i = gid; i < ghist_words; i += gsz) ghist_next[i] = 0u;
    for (uint i = gid; i < npass; i += gsz) ids[i] = 0u; /* the grid may be smaller than npass */
    const uint total = end_bit - begin_bit;
    const uint base = get_group_id(0) * SORT_BLOCK;
    uint shift = begin_bit;
    for (uint p = 0; p < npass; ++p) {
        const uint nbins = 1u << pass_width(total, npass, p);
        for (uint d = lid; d < nbins; d += SORT_WG) h[d] = 0u;
        barrier(CLK_LOCAL_MEM_FENCE);
        for (uint k = 0; k < SORT_ITEMS; ++k) {
            const uint i = base + k * SORT_WG + lid;
            if (i < n) atomic_inc(&h[digit_of(keys[i], shift, nbins)]);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (uint d = lid; d < nbins; d += SORT_WG) {
            const uint c = h[d];
            if (c) atomic_add(&ghist[p * RADIX + d], c);
        }
        barrier(CLK_LOCAL_MEM_FENCE); /* h is zeroed again for the next pass */
        shift += pass_width(total, npass, p);
    }
}

__kernel __attribute__((reqd_work_group_size(SORT_WG, 1, 1)))
void radix_onesweep(__global const key_t *keys_in, // [n]
                    __global const uint *vals_in,  // [n]
                    __global key_t *keys_out,      // [n]
                    __global uint *vals_out,       // [n]
                    const uint n,
                    const uint shift,
                    const uint nbins,
                    const uint pass,
                    __global const uint *ghist,    // [npass, RADIX] from radix_global_hist
                    __global uint *status,         // [npass, nvb, stride], this pass's part zero
                    const uint stride,
                    __global uint *ids)            // [npass] block-id counters, zero
{
    __local uint ent[2][SORT_BLOCK]; /* (digit << 16) | local index */
    __local uint tmp[SORT_WG];
    __local uint dbase[RADIX];
    __local uint dstart[RADIX];
    __local uint cnt[RADIX];         /* the block's count of each digit */
    __local uint vb_shared;
    const uint lid = get_local_id(0);
    if (lid == 0) vb_shared = atomic_inc(&ids[pass]);
    for (uint d = lid; d < nbins; d += SORT_WG) cnt[d] = 0u;
    barrier(CLK_LOCAL_MEM_FENCE);
    const uint vb = vb_shared;
    const uint nvb = virtual_blocks(n);
    const uint base = vb * SORT_BLOCK;
    const uint count = min((uint)SORT_BLOCK, n - base);
    __global uint *st = status + pass * nvb * stride;
    __global const uint *gh = ghist + pass * RADIX;

    /* 1. digits (padding: the largest digit, after every valid element) and the block's counts */
    for (uint k = 0; k < SORT_ITEMS; ++k) {
        const uint p = lid * SORT_ITEMS + k;
        const uint d = p < count ? digit_of(keys_in[base + p], shift, nbins) : nbins - 1u;
        ent[0][p] = (d << 16) | p;
        if (p < count) atomic_inc(&cnt[d]);
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* 2. publish the counts: block 0's are already its inclusive prefixes */
    for (uint j = 0; j < DIGITS_PER_ITEM; ++j) {
        const uint d = lid * DIGITS_PER_ITEM + j;
        if (d < nbins) OS_STORE(&st[vb * stride + d], ((vb == 0u ? OS_PREFIX : OS_AGGREGATE) << OS_SHIFT) | cnt[d]);
    }

    /* 3. stable local sort of the block by digit (block_sort); meanwhile the lower blocks publish */
    __local const uint *srt = block_sort(ent[0], ent[1], tmp, lid, nbins);

    /* 4. dbase[d] = sum_{d' < d} ghist[d'] + (digit d's elements in blocks < vb): the look-back reads
     *    OS_WINDOW lower blocks' words at once, adds AGGREGATEs up to the nearest PREFIX, and waits
     *    where a word is still EMPTY (that block has an id, so it runs and will publish). */
    {
        uint s = 0;
        for (uint j = 0; j < DIGITS_PER_ITEM; ++j) {
            const uint d = lid * DIGITS_PER_ITEM + j;
            if (d < nbins) s += gh[d];
        }
        uint sum;
        uint acc = wg_exclusive_scan(s, tmp, &sum);
        for (uint j = 0; j < DIGITS_PER_ITEM; ++j) {
            const uint d = lid * DIGITS_PER_ITEM + j;
            if (d >= nbins) break;
            uint excl = 0;
            if (vb > 0u) {
                int b = (int)vb - 1;
                for (;;) {
                    uint w[OS_WINDOW];
                    for (int i = 0; i < OS_WINDOW; ++i)
                        w[i] = b - i >= 0 ? OS_LOAD(&st[(uint)(b - i) * stride + d]) : (OS_PREFIX << OS_SHIFT);
                    int used = 0;
                    bool done = false;
                    for (int i = 0; i < OS_WINDOW; ++i) {
                        const uint f = w[i] >> OS_SHIFT;
                        if (f == OS_EMPTY) break;
                        excl += w[i] & OS_MASK;
                        ++used;
                        if (f == OS_PREFIX) { done = true; break; }
                    }
                    if (done) break;
                    b -= used;
                }
                OS_STORE(&st[vb * stride + d], (OS_PREFIX << OS_SHIFT) | (excl + cnt[d]));
            }
            dbase[d] = acc + excl;
            acc += gh[d];
        }
    }

    /* 5. where each digit's run starts in the sorted block; 6. the scatter (block_scatter) */
    block_scatter(srt, dstart, dbase, count, base, lid, keys_in, vals_in, keys_out, vals_out);
}

#endif
