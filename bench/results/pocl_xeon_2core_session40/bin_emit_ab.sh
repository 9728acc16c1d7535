# alternate processes: BIN_EMIT_FLAT=0 (REINGS_CL_BUILD_OPTIONS) vs default (1), fern fine state, render_vjp stage medians
# (BIN_EMIT_FLAT was a temporary define of kernels/bin.cl while this ran; adb93f8 keeps only the flat loop)
cd "$(dirname "$0")/../../.."
for r in 1 2 3 4; do
  for v in 0 1; do
    if [ $v = 0 ]; then REINGS_CL_BUILD_OPTIONS=-DBIN_EMIT_FLAT=0 .venv/bin/python bench/results/pocl_xeon_2core_session40/prof.py ${1:-fine} 15 | sed "s/^/flat=0 /"; else .venv/bin/python bench/results/pocl_xeon_2core_session40/prof.py ${1:-fine} 15 | sed "s/^/flat=1 /"; fi
  done
done
