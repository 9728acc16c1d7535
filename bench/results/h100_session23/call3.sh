set -u
# session 23, call 3 (nvidia-h100-x1). Run from the repository root: bash call3.sh .gpu_s24
# Tree: .gpu_clean (157714e + docs). Where a whole run stands now: (a) the kernel census of a fern 3v run
# (profiled: its gaps are upper bounds); (b) the profiled stage breakdown of the step at C SH 0 and SH 3.
CARRY=$1; R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/census.txt $T/prof_*.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
timeout 150 python3 bench/kernel_census.py --out $T/census.json -- eval --dataset llff --root $R/$CARRY/data/llff --scenes fern \
  --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/census_run 2>&1 \
  | grep -v "^WARNING: Target" | tail -60 > $T/census.txt
gzip -c $T/census.json > $OUT/census.json.gz; out
for sh in 0 3; do
  REINGS_QUEUE_PROFILING=1 timeout 60 python3 bench/peer_step.py --device cuda --scenes C --sh $sh --no-gsplat --ref-crop -1 2>&1 \
    | grep "device ms" > $T/prof_$sh.txt; out
done
cat $OUT/timing.txt
