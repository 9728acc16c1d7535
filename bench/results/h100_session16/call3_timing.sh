set -u
# session 16, call 3, GPU 0: sync vs sync-free binning (REINGS_BIN), one process at a time on GPU 0 while GPU 1
# runs runs3.txt. CARRY = $1. Writes /tmp/timing/*.
CARRY=$1
T=/tmp/timing; mkdir -p $T
export REINGS_CACHE_DIR=/tmp/cache
for mode in sync async; do
  for m in wall calls; do
    REINGS_BIN=$mode python3 bench/bench_host.py --device cuda:0 --mode $m --iterations 401 --label $mode \
      --json $T/bench_host.jsonl --save $T/state_${mode}_$m.npz > $T/bench_host_${mode}_$m.txt 2>&1
  done
done
python3 - <<'PY' > $T/bitcheck.txt 2>&1
import numpy as np
a = np.load('/tmp/timing/state_sync_wall.npz'); b = np.load('/tmp/timing/state_async_wall.npz')
bad = [k for k in a.files if not np.array_equal(a[k], b[k])]
print('arrays', len(a.files), 'different', bad)
PY
for rep in 1 2; do
  for mode in sync async; do
    REINGS_BIN=$mode timeout 200 bash scripts/lent_gpu.sh eval --dataset llff --root $CARRY/data/llff --scenes fern --views 3 \
      --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/fern3_${mode}_$rep 2>&1 \
      | grep -v "^WARNING: Target" > $T/fern3_${mode}_$rep.log
  done
done
for f in $T/fern3_*/llff/reings/3views/fern/metrics.json; do python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$f'.split('/')[3], round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})"; done > $T/summary.txt
rm -f $T/state_*.npz
