set -u
# session 20, call 1 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24: fern, its SfM, the 3-view stereo prior).
# (a) the opacity-only backward's bits on NVIDIA (tests/test_rasterize.py -k opacity_only, REINGS_TEST_DEVICES=cuda);
# (b) device_time.py --all, OLD (9baab14, before the opacity-only backward, ../.gpu_old) against NEW (this tree);
# (c) bench_host.py --mode wall with the queue's profiling on (NEW) and off (REINGS_QUEUE_PROFILING=0, NEWP);
# (d) fern 3 views, seed 0, full schedule: NEW, NEWP, NEWP, NEW, OLD (alternating; one H100 alone).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/device_time.txt $T/bench_host.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
prof() { case $1 in NEWP) echo 0;; *) echo 1;; esac; }
(REINGS_TEST_DEVICES=cuda timeout 120 python3 -m pytest -q -x tests/test_rasterize.py -k "opacity_only" -p no:cacheprovider 2>&1 | tail -3) > $T/tests.txt
out
for g in OLD NEW; do
  echo "device_time $g" >> $T/device_time.txt
  (cd $(src $g) && PYTHONPATH=/tmp/site:$(src $g) timeout 80 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 --all 2>&1 | grep -v "^WARNING: Target" | grep -A1 share >> $T/device_time.txt)
done
out
for g in NEW NEWP NEWP NEW; do
  echo -n "bench_host $g " >> $T/bench_host.txt
  REINGS_QUEUE_PROFILING=$(prof $g) timeout 60 python3 bench/bench_host.py --device cuda:0 --mode wall --iterations 301 2>&1 | grep -v "^WARNING: Target" | tail -1 >> $T/bench_host.txt
done
out
run() {
  name=$1; g=$2; s=$(src $g)
  (cd $s && REINGS_QUEUE_PROFILING=$(prof $g) PYTHONPATH=/tmp/site:$s timeout 80 python3 -m reings.cli eval --dataset llff --root $OLDPWD/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  out
}
run NEW_1 NEW; run NEWP_1 NEWP; run NEWP_2 NEWP; run NEW_2 NEW; run OLD_1 OLD
cat $OUT/timing.txt
