set -u
# session 23, call 4 (nvidia-h100-x1). Run from the repository root: bash call4.sh .gpu_s24
# Tree: .gpu_clean (2f80d73). How host-bound is a step now: (a) bench_host's case (every pass on) wall, with
# every launch stubbed (the host's floor) and its launch / sync counts; (b) fern 3v runs with the sync binning
# and the sync-free one (REINGS_BIN=async), alternating.
CARRY=$1; R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/host.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
for m in wall stubbed calls wall stubbed; do
  echo "== --mode $m" >> $T/host.txt
  timeout 120 python3 bench/bench_host.py --device cuda:0 --mode $m --iterations 301 --json $OUT/host.jsonl 2>&1 | grep -v "^WARNING" | tail -4 >> $T/host.txt
  out
done
run() {
  name=$1; shift
  (env "$@" timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 \
    --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "
import json, sys
m = json.load(open('$f')); s = m['seconds']
print('$name', round(m['mean']['psnr'], 6), 'training', round(sum(s[k] for k in ('coarse', 'fine', 'final')), 2), 'total', round(s['total'], 2))" >> $T/summary.txt
  out
}
run SYNC_1 REINGS_BIN=sync; run ASYNC_1 REINGS_BIN=async; run ASYNC_2 REINGS_BIN=async; run SYNC_2 REINGS_BIN=sync
cat $OUT/timing.txt
