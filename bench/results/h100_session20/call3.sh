set -u
# session 20, call 3 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24).
# OLD = 61286cf (../.gpu_old); NEW = this tree (isect_reduce loads 8 records before adding them, same order).
# (a) isect_reduce's bits on NVIDIA; (b) device_time.py --all OLD / NEW; (c) fern 3 views, seed 0, full schedule:
# OLD, NEW, NEW with the sync-free binning (REINGS_BIN=async), twice, alternating.
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/device_time.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
env_of() { case $1 in ASYNC) echo "REINGS_BIN=async";; *) echo "REINGS_BIN=sync";; esac; }
(REINGS_TEST_DEVICES=cuda timeout 100 python3 -m pytest -q tests/test_rasterize.py -k "reduce" -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
out
for g in OLD NEW OLD NEW; do
  echo "device_time $g" >> $T/device_time.txt
  (cd $(src $g) && PYTHONPATH=/tmp/site:$(src $g) timeout 80 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 --all 2>&1 | grep -v "^WARNING: Target" | grep -A1 share | tail -1 >> $T/device_time.txt)
done
out
run() {
  name=$1; g=$2; s=$(src $g)
  (cd $s && env $(env_of $g) PYTHONPATH=/tmp/site:$s timeout 75 python3 -m reings.cli eval --dataset llff --root $OLDPWD/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  out
}
run OLD_1 OLD; run NEW_1 NEW; run ASYNC_1 ASYNC; run OLD_2 OLD; run NEW_2 NEW; run ASYNC_2 ASYNC
cat $OUT/timing.txt
