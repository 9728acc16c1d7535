/* gather_rows.cl: dst[r, c] = src[idx[r], c] over n_new rows of `width` 32-bit words, and 0 where
   idx[r] < 0: the rows of a new row set of the training state (reings.types.RowPlan), gathered on
   the device instead of the state going to the host and back (the device trainer's `apply_rows`:
   the densification's clones, split children and prunes, and the prune of the Gaussians no
   training view sees). Parameters gather their source rows; Adam moments and statistics their
   kept rows, zeros for new ones. Words are copied as uint: the bits of float and int rows alike.
   Twin: reings.backends.reference_state.gather_rows (tests/test_apply_rows.py). */

__kernel void gather_rows(const uint n_words,               /* n_new * width */
                          const uint width,                 /* words per row */
                          __global const int *idx,          /* [n_new] source rows, or < 0 for zeros */
                          __global const uint *src,         /* [>= max(idx) + 1, width] */
                          __global uint *dst)               /* [n_new, width] */
{
    const uint i = get_global_id(0);
    if (!(i < n_words)) return;
    const uint r = i / width, c = i - r * width;
    const int s = idx[r];
    dst[i] = s < 0 ? 0u : src[(size_t)s * width + c];
}
