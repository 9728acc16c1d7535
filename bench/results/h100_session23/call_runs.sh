set -u
# copied from bench/results/h100_session11/call_runs.sh (session 11): full-schedule runs on a lent machine, one `reings eval` process per run, pinned to a
# GPU by --device cuda:G (no Dask: each line of RUNS is its own variant). Usage:
#   bash bench/results/h100_session23/call_runs.sh CARRY LIMIT_S RUNS_FILE
# RUNS_FILE lines: NAME GPU DATASET SCENE VIEWS SEED [extra reings eval options...]
CARRY=$1; LIM=$2; RUNS=$3
mkdir -p /tmp/cache /tmp/g; cp -r $CARRY/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
t0=$(date +%s)
while read -r name gpu ds scene views seed extra; do
  [ -z "$name" ] && continue
  case "$name" in \#*) continue;; esac
  root=$CARRY/data/$ds
  (timeout $LIM bash scripts/lent_gpu.sh eval --dataset $ds --root $root --scenes $scene --views $views \
     --seeds $seed --methods reings --preset paper --device cuda:$gpu --no-lpips --out /tmp/g/$name $extra 2>&1 \
     | grep -v "^WARNING: Target" > /tmp/g/$name.$scene.$views.$seed.log) &
done < $RUNS
sleep 60; nvidia-smi > /tmp/g/nvidia_smi_60s.txt
wait
echo "runs $(( $(date +%s) - t0 )) s, metrics $(find /tmp/g -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json | sort); do python3 -c "import json,sys; m=json.load(open('$f')); print('$f'.split('/')[3], m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m['gaussians'].get('final_prune'), round(m['seconds']['method'],1), round(m['seconds']['total'],1))"; done
