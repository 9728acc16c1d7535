set -u
# session 24, call 2 (nvidia-h100-x1). Run from the repository root: bash call2.sh .gpu_s24
# (a) launch_cost (invoker / preset / direct / direct_preset); (b) bench_host wall, both launch modes;
# (c) host_wait around fern 3v seed 0 full schedule, REINGS_LAUNCH=pyopencl / direct alternating (.gpu_clean = HEAD + launch.py).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/launch.txt $T/host.txt 2>/dev/null; for f in $T/hw_*.txt; do echo "== $f"; cat $f; done 2>/dev/null; } > $OUT/timing.txt; }
S=$R/.gpu_clean
(cd $S && PYTHONPATH=/tmp/site:$S timeout 120 python3 bench/launch_cost.py --device cuda:0 --json $OUT/launch.jsonl > $T/launch.txt 2>&1)
out
for m in pyopencl direct pyopencl direct; do
  (cd $S && REINGS_LAUNCH=$m PYTHONPATH=/tmp/site:$S timeout 60 python3 bench/bench_host.py --device cuda:0 --mode wall --iterations 301 --label $m --json $OUT/host.jsonl 2>&1 | grep "ms/iteration" >> $T/host.txt)
done
out
run() {
  name=$1; mode=$2
  (cd $S && REINGS_LAUNCH=$mode PYTHONPATH=/tmp/site:$S timeout 110 python3 bench/host_wait.py --out $OUT/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -7 > $T/hw_$name.txt)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  out
}
run py_1 pyopencl; run direct_1 direct; run py_2 pyopencl; run direct_2 direct; run py_3 pyopencl; run direct_3 direct
cat $OUT/timing.txt
