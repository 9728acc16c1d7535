set -u
# session 19, call 6 (nvidia-h100-x1, one H100 alone): the opacity-only backward (RASTER_BWD_OPACITY; NEW, this
# tree) against HEAD 9baab14 (OLD, ../.gpu_old): device_time.py --all twice each, alternating, then fern 3 views,
# seed 0, full schedule, alternating, two rounds (the whole-run effect is predicted below call 4's host noise).
# CARRY = $1 (.gpu_s24).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/device_time.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
for rep in 1 2; do for g in OLD NEW; do
  echo "device_time $g-$rep" >> $T/device_time.txt
  (cd $(src $g) && PYTHONPATH=/tmp/site:$(src $g) timeout 60 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 --all 2>&1 | grep -v "^WARNING: Target" | grep -A1 share >> $T/device_time.txt)
done; done
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
run OLD_1 OLD; run NEW_1 NEW; run OLD_2 OLD; run NEW_2 NEW
cat $OUT/timing.txt
