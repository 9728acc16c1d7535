#!/usr/bin/env bash
# A `reings eval` grid on one GPU: WORKERS concurrent workers share one --out (per-run locks).
# Carry .whl (wheels) and .gpudata (data under .gpudata/<dataset>, SfM cache under .gpudata/cache).
# CACHE: the SfM/depth cache folder (default .gpudata/cache); RENDERS=1: keep the test renders.
# usage: DATASET=llff SCENES=fern,flower VIEWS=3 METHODS=reings SEEDS=0,1,2 WORKERS=6 TAG=x scripts/gpu_eval_grid.sh [extra eval options]
set -u
OUT=${OUT:-/tmp/out}; ROOT=$PWD
[ -d /tmp/site/pyopencl ] || python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null || exit 1
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=${CACHE:-$ROOT/.gpudata/cache} PYTHONPATH=/tmp/site:$ROOT
G=/tmp/g/$TAG; L=/tmp/g/${TAG}_logs; mkdir -p $OUT $L $G
T0=$(date +%s)
for w in $(seq 1 $WORKERS); do
  timeout ${LIMIT:-520} python3 -m reings.cli eval --dataset $DATASET --root $ROOT/.gpudata/$DATASET --scenes $SCENES \
    --views $VIEWS --methods $METHODS --seeds $SEEDS --preset paper --device cuda --out $G --no-lpips "$@" \
    > $L/w$w.txt 2>&1 &
  sleep 2
done
wait
echo "elapsed $(( $(date +%s) - T0 )) s"
python3 -m reings.cli eval --table-only --out $G > /dev/null 2>&1; sed -n '/^| Method/,/^$/p' $G/results.md | head -30
find $G -name metrics.json | while read f; do python3 - "$f" <<'PY'
import json,sys
p=sys.argv[1]; m=json.load(open(p))
for st in m.get('stages',[]): st.pop('history',None)
json.dump(m,open(p,'w'))
PY
done
find $G -name .lock -delete
# RENDERS=1 keeps the test renders (for scripts/rescore_lpips.py); pieces of 15 MB (the device tool's file limit)
if [ "${RENDERS:-0}" = 1 ]; then EXC="--exclude=depths"; else EXC="--exclude=*.png"; fi
tar czf /tmp/$TAG.tgz $EXC --exclude='*.ply' --exclude='checkpoints' -C /tmp/g $TAG ${TAG}_logs
split -b 15m -d /tmp/$TAG.tgz $OUT/$TAG.tgz.
