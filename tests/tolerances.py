"""Named tolerances, each with its reason (STYLE.md §3.7). Import these; never inline numbers."""

# --- float64 reference vs its own central finite differences (tests/test_reference_fd.py) ------
FD_STEP = 1e-6  # central step in float64: truncation O(h²)≈1e-12, round-off O(eps·|L|/h)≈1e-10·|L|
FD_RTOL = 1e-6  # |AD-FD| <= FD_ATOL_REL*max|FD| + FD_RTOL*|FD|: the chain is exact, so errors are FD noise
FD_ATOL_REL = 1e-6  # absolute slack relative to the largest |FD| of the field (round-off floor of tiny components)

# --- float32 device vs float64 reference, forward ------------------------------------------------
RASTER_FWD_ATOL = 1e-4  # issue §5: rgb/depth/alpha max error 1e-4 away from discontinuities
RASTER_FWD_RTOL = 0.0  # the bound is absolute (images are O(1)); depth tests may scale it
PROJECT_FWD_RTOL = 1e-5  # float32 projection: a few ulp per op through ~30 ops
PROJECT_FWD_ATOL = 1e-5  # absolute floor for components near zero (float32 cancellation)

# --- float32 device vs float64 reference, gradients ----------------------------------------------
MIN_COSINE = 0.999  # issue §5: per-field gradient cosine similarity
MAX_REL_L2 = 1e-3  # issue §5: per-field relative L2 error of the gradient
MAX_SIGNED_BIAS = 1e-3  # |mean(actual-expected)| / rms(expected): catches a systematic bias the cosine misses

# --- discontinuity bands -------------------------------------------------------------------------
MAX_FLIP_FRACTION = 1e-3  # pixels inside a 1/255, T_MIN or tile-edge band that may differ (float32 vs 64)
