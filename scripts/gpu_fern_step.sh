#!/usr/bin/env bash
# Carry .whl (wheels) and .gpudata (data under .gpudata/{llff,dtu}, SfM cache under .gpudata/cache,
# and for the before/after script a copy of the older tree under .gpudata/before: git archive REV reings kernels bench pyproject.toml).
# usage: gpu_call.sh TREE TAG   (TREE: code root to run; TAG: output name)
set -u
TREE=$1; TAG=$2; OUT=${OUT:-/tmp/out}
ROOT=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16 PYTHONUNBUFFERED=1
export REINGS_CACHE_DIR=$ROOT/.gpudata/cache
cd $TREE; export PYTHONPATH=/tmp/site:$PWD
mkdir -p $OUT/$TAG /tmp/runs_$TAG
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/$TAG/machine.txt
if [ "${STEP:-1}" = 1 ]; then
timeout ${STEP_TIMEOUT:-300} python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json $OUT/$TAG/step.jsonl > $OUT/$TAG/step.txt 2>&1; tail -20 $OUT/$TAG/step.txt
fi
for r in ${RUNS:-a b}; do
  timeout 400 python3 -m reings.cli run --data $ROOT/.gpudata/llff/fern --views 3 --device cuda --preset paper --out /tmp/runs_$TAG/fern3_$r --overwrite --no-lpips > $OUT/$TAG/fern_$r.txt 2>&1 &
done
wait
for r in ${RUNS:-a b}; do tail -2 $OUT/$TAG/fern_$r.txt; cp /tmp/runs_$TAG/fern3_$r/metrics.json $OUT/$TAG/metrics_fern3_$r.json; done
