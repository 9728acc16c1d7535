set -u
# bench/results/h100_session11/call_runs.sh without its install, cache copy and pack (the caller does them once,
# so two of these can run side by side). Usage: bash call_runs_nopack.sh CARRY LIMIT_S RUNS_FILE
# RUNS_FILE lines: NAME GPU DATASET SCENE VIEWS SEED [extra reings eval options...]
CARRY=$1; LIM=$2; RUNS=$3
t0=$(date +%s)
while read -r name gpu ds scene views seed extra; do
  [ -z "$name" ] && continue
  case "$name" in \#*) continue;; esac
  root=$CARRY/data/$ds
  (timeout $LIM bash scripts/lent_gpu.sh eval --dataset $ds --root $root --scenes $scene --views $views \
     --seeds $seed --methods reings --preset paper --device cuda:$gpu --no-lpips --out /tmp/g/$name $extra 2>&1 \
     | grep -v "^WARNING: Target" > /tmp/g/$name.$scene.$views.$seed.log) &
done < $RUNS
wait
echo "runs $(( $(date +%s) - t0 )) s"
for f in $(find /tmp/g -name metrics.json | sort); do python3 -c "import json,sys; m=json.load(open('$f')); print('$f'.split('/')[3], m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m['gaussians'].get('final_prune'), round(m['seconds']['method'],1), round(m['seconds']['total'],1))"; done
