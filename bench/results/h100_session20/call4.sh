set -u
# session 20, call 4 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24).
# OLD = HEAD (../.gpu_old); NEW = this tree: densify_and_prune's growth and prune in one index op, the trainer's
# state download / upload and importance reads non-blocking with one wait each, isect_reduce loading 8 records ahead
# (all the same bits). (a) bits on NVIDIA; (b) fern 3v seed 0 full schedule OLD, NEW, NEW, OLD; (c) the kernel
# census of OLD and NEW (isect_reduce's device time on fern's segments).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/summary.txt $T/census_*.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
(REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q tests/test_rasterize.py tests/test_device_fit.py tests/test_prune_unseen.py -k "reduce or fit or prune or importance" -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
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
for g in OLD NEW; do
  s=$(src $g)
  (cd $s && PYTHONPATH=/tmp/site:$s timeout 100 python3 bench/kernel_census.py --out $OUT/census_$g.json -- eval --dataset llff --root $OLDPWD/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/census_run_$g 2>&1 | grep -v "^WARNING: Target" | grep -A1 "^coarse \|^fine \|^final " > $T/census_$g.txt)
  out
done
cat $OUT/timing.txt
