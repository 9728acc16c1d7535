set -u
# session 46, call 1: the kernels changed this session on NVIDIA (the opacity count's compare where the device has
# doubles; isect_reduce's REDUCE_CHUNK and tile_ranges' TR_CHUNK on the CPU schedule, which NVIDIA's compiler builds in
# the tests, through vload8 there), then the default fern run at 3 views, seeds 0-2, one run at a time (issue 15's
# GPU point: <= 30 s of training, <= 40 s end to end)
PAR=1; source bench/gpu_call_env.sh .gpu30 470
REINGS_TEST_DEVICES=cuda timeout 240 python3 -m pytest -q -p no:cacheprovider tests/test_adam_kernel.py tests/test_bin.py \
  tests/test_rasterize.py -k "not oclgrind and (opacity_count or regularizer or isect_reduce or bin or test_bin)" 2>&1 | tail -4 > "$OUT/tests.txt"
one default llff fern 3 0 paper
one default llff fern 3 1 paper
one default llff fern 3 2 paper
finish
cat "$OUT/tests.txt"
