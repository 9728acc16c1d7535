set -u
# session 24, call 3 (nvidia-h100-x1). Run from the repository root: bash call3.sh .gpu_s24
# fern 3v seed 0 full schedule under host_wait: OLD (.gpu_old = 2282da9), NEW (.gpu_clean), NEW async+11 bits, alternating.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; for f in $T/hw_*.txt; do echo "== $f"; cat $f; done 2>/dev/null; } > $OUT/timing.txt; }
cp $R/.gpu_clean/bench/host_wait.py $R/.gpu_old/bench/host_wait.py
run() {
  name=$1; tree=$2; shift 2
  S=$R/$tree
  (cd $S && env "$@" PYTHONPATH=/tmp/site:$S timeout 110 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'binning', m.get('memory',{}).get('binning'))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  out
}
run old_1 .gpu_old X=1; run new_1 .gpu_clean X=1; run async_1 .gpu_clean REINGS_BIN=async REINGS_SORT_BITS=11
run old_2 .gpu_old X=1; run new_2 .gpu_clean X=1; run async_2 .gpu_clean REINGS_BIN=async REINGS_SORT_BITS=11
run old_3 .gpu_old X=1; run new_3 .gpu_clean X=1; run async_3 .gpu_clean REINGS_BIN=async REINGS_SORT_BITS=11
tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
cat $OUT/timing.txt
