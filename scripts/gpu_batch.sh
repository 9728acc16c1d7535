#!/usr/bin/env bash
# One batched call on the lent NVIDIA machine. Sections run in the order given by STEPS (space
# separated); each writes its log under $OUT. Carry: .whl (wheels) and .gpudata (data + caches).
#   tests  the OpenCL test suite on device "cuda" (pytest_cuda.txt)
#   fit    bench/bench_fit.py: host vs device engine ms/iteration (fit_cuda.txt/.jsonl)
#   step   bench/peer_step.py: our training step vs gsplat's, same arrays, same process (step.txt)
#   bench  reings bench --device cuda, and the gsplat peer (bench_cuda.txt)
#   pocl2  PoCL pinned to 2 cores: reings bench scene A, the sort bench (pocl2.txt)
#   fern   reings run, paper preset, fern 3 views, on cuda (runs.tgz)
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
STEPS=${STEPS:-"tests fit bench pocl2"}
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=$PWD/.gpudata/cache
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 -m reings.cli devices; } > "$OUT/machine.txt" 2>&1
cat "$OUT/machine.txt"
R="python3 -m reings.cli"
for s in $STEPS; do
  echo "=== $s $(date +%T)"
  case $s in
    tests)
      REINGS_TEST_DEVICES=cuda timeout ${TEST_TIMEOUT:-420} python3 -m pytest -q -ra -p no:cacheprovider \
        tests/test_project.py tests/test_bin.py tests/test_sort.py tests/test_rasterize.py tests/test_render.py \
        tests/test_hard_cases.py tests/test_losses.py tests/test_adam_kernel.py tests/test_device_fit.py tests/test_peer_step.py tests/test_depth_loss_kernel.py \
        ${EXTRA_TESTS:-} > "$OUT/pytest_cuda.txt" 2>&1; tail -5 "$OUT/pytest_cuda.txt" ;;
    fit)
      { timeout 200 python3 bench/bench_fit.py --device cuda --json "$OUT/fit_cuda.jsonl";
        timeout 120 python3 bench/bench_fit.py --device cuda --engines device --width 504 --height 378 --json "$OUT/fit_cuda.jsonl";
        timeout 60 python3 bench/bench_fit.py --device cuda --adam-only; } > "$OUT/fit_cuda.txt" 2>&1; tail -40 "$OUT/fit_cuda.txt" ;;
    step)
      { timeout ${STEP_TIMEOUT:-300} python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json "$OUT/step.jsonl";
        timeout 120 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --no-flush --no-breakdown --ref-crop -1 --no-gsplat --json "$OUT/step.jsonl";
        timeout 60 python3 bench/peer_step.py --device cuda --overhead --json "$OUT/step.jsonl"; } > "$OUT/step.txt" 2>&1; tail -45 "$OUT/step.txt" ;;
    bench)
      { timeout 150 $R bench --device cuda --out "$OUT/bench_cuda.jsonl";
        timeout 200 python3 bench/peer_gsplat.py --json "$OUT/bench_cuda.jsonl"; } > "$OUT/bench_cuda.txt" 2>&1; tail -30 "$OUT/bench_cuda.txt" ;;
    pocl2)
      { taskset -c 0,1 timeout 300 $R bench --device pocl --scenes A --warmup 3 --repeats 15 --out "$OUT/pocl2.jsonl";
        taskset -c 0,1 timeout 120 python3 bench/bench_sort.py --device pocl; } > "$OUT/pocl2.txt" 2>&1; tail -30 "$OUT/pocl2.txt" ;;
    fern)
      mkdir -p /tmp/runs
      timeout ${FERN_TIMEOUT:-400} $R run --data .gpudata/llff/fern --views 3 --device cuda --preset paper \
        --out /tmp/runs/fern3_cuda --overwrite --no-lpips > "$OUT/fern.txt" 2>&1; grep -a "^\[\|PSNR" "$OUT/fern.txt" | tail -12
      tar czf "$OUT/runs.tgz" -C /tmp runs ;;
  esac
done
echo "=== done $(date +%T)"
