set -u
# (BIN_TIGHT was not kept: rerun on 53685df with bench/results/pocl_xeon_2core_session45/bin_tight.patch applied)
# session 45, call 2: BIN_TIGHT with each row's run of kept tiles (TIGHT_ROWS; call 1's form tested every tile of the
# rect, and its bin_count looped over whole rects): the binning tests on NVIDIA, then the default fern run at 3 views,
# seeds 0-2, one run at a time, binned tight (the default) and whole (REINGS_TIGHT_TILES=0), the order alternating
PAR=1; source bench/gpu_call_env.sh .gpu30 470
REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_bin.py tests/test_tile_extent.py -p no:cacheprovider \
  -k "not oclgrind" 2>&1 | tail -4 > "$OUT/tests.txt"
whole() { export REINGS_TIGHT_TILES=0; one whole llff fern 3 $1 paper; unset REINGS_TIGHT_TILES; }
one tight llff fern 3 0 paper; whole 0
whole 1; one tight llff fern 3 1 paper
one tight llff fern 3 2 paper; whole 2
finish
cat "$OUT/tests.txt"
