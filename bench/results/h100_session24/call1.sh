set -u
# session 24, call 1 (nvidia-h100-x1). Run from the repository root: bash call1.sh .gpu_s24
# (a) launch_cost (host vs device cost of a launch); (b) host_wait around fern 3v seed 0 full schedule, sync / async
# binning alternating (the tree at HEAD, .gpu_clean).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/launch.txt 2>/dev/null; for f in $T/hw_*.txt; do echo "== $f"; cat $f; done 2>/dev/null; } > $OUT/timing.txt; }
S=$R/.gpu_clean
(cd $S && PYTHONPATH=/tmp/site:$S timeout 120 python3 bench/launch_cost.py --device cuda:0 --json $OUT/launch.jsonl > $T/launch.txt 2>&1)
out
run() {
  name=$1; mode=$2
  (cd $S && REINGS_BIN=$mode PYTHONPATH=/tmp/site:$S timeout 110 python3 bench/host_wait.py --out $OUT/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -7 > $T/hw_$name.txt)
  out
}
run sync_1 sync; run async_1 async; run sync_2 sync; run async_2 async
cat $OUT/timing.txt
