set -u
# session 17, call 3. GPU 1: runs3.txt (call_runs.sh, in the background). GPU 0, one process at a time:
# (1) bench_host.py with the depth sort per forward (REINGS_DEPTH_ORDER=sort) and shared (share), alternating, and
# a bit check of the final states; (2) fern 3 views, seed 0, full schedule: the old default (sort, soft depth pass
# of its own), shared depth order alone, shared depth order + --soft-depth-shared true (the candidate default).
# CARRY = $1 (.gpu_s21: fern, NeX trex + room, SfM caches, fern's 3-view stereo cache). Writes $OUT/timing.txt.
CARRY=$1
(bash bench/results/h100_session11/call_runs.sh $CARRY 470 bench/results/h100_session17/runs3.txt > /tmp/batch.txt 2>&1) &
sleep 25
T=/tmp/timing; mkdir -p $T
export REINGS_CACHE_DIR=/tmp/cache
for rep in 1 2; do
  for mode in sort share; do
    REINGS_DEPTH_ORDER=$mode python3 bench/bench_host.py --device cuda:0 --mode wall --iterations 401 --label $mode-$rep \
      --json $T/bench_host.jsonl --save $T/state_$mode.npz 2>&1 | grep -v "^WARNING: Target" >> $T/bench_host.txt
  done
done
python3 - >> $T/bench_host.txt 2>&1 <<'PY'
import numpy as np
a = np.load('/tmp/timing/state_sort.npz'); b = np.load('/tmp/timing/state_share.npz')
print('arrays', len(a.files), 'different', [k for k in a.files if not np.array_equal(a[k], b[k])])
PY
timeout 100 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 2 2>&1 | grep -v "^WARNING: Target" >> $T/bench_host.txt
run() {  # NAME ORDER [options]
  name=$1; order=$2; shift 2
  REINGS_DEPTH_ORDER=$order timeout 150 bash scripts/lent_gpu.sh eval --dataset llff --root $CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name "$@" 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/bench_host.txt; cat $T/summary.txt; } > $OUT/timing.txt
}
run old_1 sort --soft-depth-shared false
run new_1 share --soft-depth-shared true
run share_1 share --soft-depth-shared false
run old_2 sort --soft-depth-shared false
rm -f $T/state_*.npz
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/bench_host.txt; cat $T/summary.txt; } > $OUT/timing.txt
cat $OUT/timing.txt
wait
cat /tmp/batch.txt | tail -12
