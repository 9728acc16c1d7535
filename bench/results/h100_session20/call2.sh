set -u
# session 20, call 2 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24).
# (a) the new kernels' bits on NVIDIA: rasterize_bwd with a second depth cotangent (RASTER_BWD_DEPTH_O) against
#     its own opacity-only pass, isect_reduce's register pass in record order, the fused fit against the unfused;
# (b) device_time.py --all, OLD (08cade0: queues unprofiled, ../.gpu_old) against NEW (this tree: the fused soft
#     backward, isect_reduce in one pass);
# (c) fern 3 views, seed 0, full schedule: OLD, NEW, NEW, OLD (alternating; one H100 alone);
# (d) the kernel census of NEW (profiled: its gaps are upper bounds, its kernel times are not affected).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/device_time.txt $T/summary.txt $T/census.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
(REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_rasterize.py tests/test_device_fit.py -k "second_depth or isect_reduce or fused or opacity_only or shared_soft" -p no:cacheprovider 2>&1 | tail -4) > $T/tests.txt
out
for g in OLD NEW; do
  echo "device_time $g" >> $T/device_time.txt
  (cd $(src $g) && PYTHONPATH=/tmp/site:$(src $g) timeout 80 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 --all 2>&1 | grep -v "^WARNING: Target" | grep -A1 share >> $T/device_time.txt)
done
out
run() {
  name=$1; g=$2; s=$(src $g)
  (cd $s && PYTHONPATH=/tmp/site:$s timeout 75 python3 -m reings.cli eval --dataset llff --root $OLDPWD/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  out
}
run OLD_1 OLD; run NEW_1 NEW; run NEW_2 NEW; run OLD_2 OLD
timeout 100 python3 bench/kernel_census.py --out $OUT/census.json -- eval --dataset llff --root $CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/census_run 2>&1 | grep -v "^WARNING: Target" | tail -40 > $T/census.txt
out
cat $OUT/timing.txt
