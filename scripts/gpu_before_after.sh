#!/usr/bin/env bash
# Carry .whl (wheels) and .gpudata (data under .gpudata/{llff,dtu}, SfM cache under .gpudata/cache,
# and for the before/after script a copy of the older tree under .gpudata/before: git archive REV reings kernels bench pyproject.toml).
# After-call: new tree ($PWD) vs cee3c25 (.gpudata/before) on one machine.
set -u
OUT=${OUT:-/tmp/out}; ROOT=$PWD; BEFORE=$ROOT/.gpudata/before
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=$ROOT/.gpudata/cache
mkdir -p $OUT/after $OUT/beforeb /tmp/runs
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; } > $OUT/after/machine.txt
# PoCL bench, 2 pinned cores, before then after (in the background, cores 0-1)
( cd $BEFORE && PYTHONPATH=/tmp/site:$BEFORE taskset -c 0,1 timeout 280 python3 -m reings.cli bench --device pocl --scenes A --warmup 3 --repeats 15 --out $OUT/beforeb/pocl2.jsonl > $OUT/beforeb/pocl2.txt 2>&1
  cd $ROOT && PYTHONPATH=/tmp/site:$ROOT taskset -c 0,1 timeout 280 python3 -m reings.cli bench --device pocl --scenes A --warmup 3 --repeats 15 --out $OUT/after/pocl2.jsonl > $OUT/after/pocl2.txt 2>&1 ) &
PB=$!
# GPU step: after, then before, same machine (cores 2-15)
cd $ROOT && PYTHONPATH=/tmp/site:$ROOT taskset -c 2-15 timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json $OUT/after/step.jsonl > $OUT/after/step.txt 2>&1
cd $BEFORE && PYTHONPATH=/tmp/site:$BEFORE taskset -c 2-15 timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json $OUT/beforeb/step.jsonl > $OUT/beforeb/step.txt 2>&1
# fern paper run with the new code (bit-identity vs the first call), and CUDA tests
cd $ROOT && export PYTHONPATH=/tmp/site:$ROOT
taskset -c 2-15 timeout 300 python3 -m reings.cli run --data $ROOT/.gpudata/llff/fern --views 3 --device cuda --preset paper --out /tmp/runs/fern3 --overwrite --no-lpips > $OUT/after/fern.txt 2>&1 &
REINGS_TEST_DEVICES=cuda taskset -c 2-15 timeout 400 python3 -m pytest -q -ra -p no:cacheprovider -m "not oclgrind" tests/test_device_fit.py tests/test_adam_kernel.py tests/test_depth_loss_kernel.py tests/test_losses.py tests/test_train.py tests/test_view_warp.py tests/test_render.py ${EXTRA_TESTS:-} > $OUT/after/pytest_cuda.txt 2>&1
wait
cp /tmp/runs/fern3/metrics.json $OUT/after/metrics_fern3.json; cp /tmp/runs/fern3/config.toml $OUT/after/ 2>/dev/null
tail -3 $OUT/after/pytest_cuda.txt; tail -2 $OUT/after/fern.txt
grep -h "^ *[ABC] " $OUT/after/step.txt $OUT/beforeb/step.txt; tail -4 $OUT/after/pocl2.txt $OUT/beforeb/pocl2.txt
tar czf $OUT/res.tgz -C $OUT after beforeb
