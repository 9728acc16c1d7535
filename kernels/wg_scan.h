/* wg_scan.h: exclusive prefix sum over one work-group, shared by scan.cl and sort.cl.
 *
 * Include after defining WG_SCAN_SIZE (the work-group size, a power of two).
 * wg_exclusive_scan(x, tmp, &sum): each work-item gets the sum of x over the work-items before
 * it; *sum gets the group total. tmp: WG_SCAN_SIZE uints of local memory. Hillis-Steele,
 * 2*log2(WG_SCAN_SIZE) barriers; every work-item of the group must call it. */
#ifndef REINGS_WG_SCAN_H
#define REINGS_WG_SCAN_H
#ifndef WG_SCAN_SIZE
#error "define WG_SCAN_SIZE before including wg_scan.h"
#endif

static inline uint wg_exclusive_scan(uint x, __local uint *tmp, uint *sum)
{
    const uint lid = get_local_id(0);
    tmp[lid] = x;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (uint off = 1; off < WG_SCAN_SIZE; off <<= 1) {
        const uint t = lid >= off ? tmp[lid - off] : 0u;
        barrier(CLK_LOCAL_MEM_FENCE);
        tmp[lid] += t;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    const uint incl = tmp[lid];
    *sum = tmp[WG_SCAN_SIZE - 1];
    barrier(CLK_LOCAL_MEM_FENCE); /* tmp may be reused right after */
    return incl - x;
}
#endif
