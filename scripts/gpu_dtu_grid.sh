#!/usr/bin/env bash
# Carry .whl (wheels) and .gpudata (data under .gpudata/{llff,dtu}, SfM cache under .gpudata/cache,
# and for the before/after script a copy of the older tree under .gpudata/before: git archive REV reings kernels bench pyproject.toml).
# DTU scan24 grid on one GPU: N concurrent `reings eval` workers share each --out (per-run locks).
# usage: gpu_dtu.sh "GRID..." where GRID = recipe:views:seeds:workers
set -u
OUT=${OUT:-/tmp/out}; ROOT=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=$ROOT/.gpudata/cache PYTHONPATH=/tmp/site:$ROOT
mkdir -p $OUT/logs /tmp/g
T0=$(date +%s)
for grid in $1; do
  IFS=: read rec views seeds workers <<< "$grid"
  for w in $(seq 1 $workers); do
    timeout ${LIMIT:-520} python3 -m reings.cli eval --dataset dtu --root $ROOT/.gpudata/dtu --scenes scan24 --views $views \
      --methods reings,dngaussian --seeds $seeds --preset paper --device cuda --out /tmp/g/$rec --no-lpips --recipe $rec \
      > $OUT/logs/${rec}_v${views}_w$w.txt 2>&1 &
    sleep 2
  done
done
wait
echo "elapsed $(( $(date +%s) - T0 )) s"
for d in /tmp/g/*; do python3 -m reings.cli eval --table-only --out $d > /dev/null 2>&1; echo "== $d"; cat $d/results.md 2>/dev/null | head -40; done
cd /tmp/g && find . -name metrics.json | while read f; do python3 - "$f" <<'PY'
import json,sys
p=sys.argv[1]; m=json.load(open(p))
for st in m.get('stages',[]): st.pop('history',None)
json.dump(m,open(p,'w'))
PY
done
tar czf $OUT/dtu.tgz --exclude='*.png' --exclude='*.ply' --exclude='checkpoints' -C /tmp g
