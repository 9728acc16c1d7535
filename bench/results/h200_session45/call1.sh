set -u
# (BIN_TIGHT was not kept: rerun on 53685df with bench/results/pocl_xeon_2core_session45/bin_tight.patch applied)
# session 45, call 1: bin.cl's BIN_TIGHT on NVIDIA's OpenCL: the binning tests (the device's decisions = the float32
# twin's, the identity of the images and gradients), then the default fern run at 3 views, seeds 0-2, one run at a
# time, binned tight (the default) and binned whole (REINGS_TIGHT_TILES=0), alternating
PAR=1; source bench/gpu_call_env.sh .gpu30 470
REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_bin.py tests/test_tile_extent.py -p no:cacheprovider \
  -k "not oclgrind" 2>&1 | tail -8 > "$OUT/tests.txt"
for s in 0 1 2; do
  one tight llff fern 3 $s paper
  export REINGS_TIGHT_TILES=0; one whole llff fern 3 $s paper; unset REINGS_TIGHT_TILES
done
finish
cat "$OUT/tests.txt"
