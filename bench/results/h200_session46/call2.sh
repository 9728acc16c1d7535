set -u
# session 46, call 2: the final tree's changed paths on NVIDIA (SSIM_VTAIL in the CPU schedule's photometric kernels,
# which NVIDIA's compiler builds in the tests; bin.cl's one program with TR_CHUNK; the kernel-build test)
PAR=1; source bench/gpu_call_env.sh .gpu30 470
REINGS_TEST_DEVICES=cuda timeout 400 python3 -m pytest -q -p no:cacheprovider tests/test_losses.py tests/test_bin.py \
  tests/test_kernel_builds.py tests/test_adam_kernel.py -k "not oclgrind" 2>&1 | tail -4 > "$OUT/tests.txt"
cat "$OUT/tests.txt"
