/* gather_rows.cl: dst[r, c] = src[idx[r], c] over n_new rows of `width` 32-bit words: the rows a
   host-side prune kept (reings.state.apply_index_op(keep=)), gathered on the device instead of the
   state going up again (the device trainer's `keep_rows`: the densification's prune of the Gaussians
   no training view sees). Words are copied as uint: the bits of float and int rows alike. Twin:
   numpy fancy indexing a[idx] (tests/test_keep_rows.py). */

__kernel void gather_rows(const uint n_words,               /* n_new * width */
                          const uint width,                 /* words per row */
                          __global const int *idx,          /* [n_new] source rows, ascending */
                          __global const uint *src,         /* [>= max(idx) + 1, width] */
                          __global uint *dst)               /* [n_new, width] */
{
    const uint i = get_global_id(0);
    if (!(i < n_words)) return;
    const uint r = i / width, c = i - r * width;
    dst[i] = src[(size_t)idx[r] * width + c];
}
