set -u
# session 22, call 2 (nvidia-h100-x1). Run from the repository root: bash call2.sh .gpu_s24
# Tree: 00c838b (.gpu_clean). Experiment: queue.flush() after every K-th launch (flush_probe.py), with the
# sync and the sync-free binning. (a) bench_host.py wall, 301 iterations, two rounds; (b) fern 3v seed 0 full
# runs: K = 0 and the fastest K of (a), alternating, and the sync-free binning with that K.
CARRY=$1; R=$PWD; S=$R/.gpu_clean; P=$R/bench/results/h100_session22/flush_probe.py
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S REINGS_SRC=$S
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/host.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
for round in 1 2; do
  for bin in sync async; do
    for k in 0 1 4 16; do
      echo -n "round $round bin $bin K $k: " >> $T/host.txt
      REINGS_BIN=$bin timeout 60 python3 $P $k host --device cuda:0 --mode wall --iterations 301 --json $T/host.jsonl 2>&1 | grep "^wall" | cut -c1-60 >> $T/host.txt
      out
    done
  done
done
BEST=$(python3 - <<'PY'
import re, collections
d = collections.defaultdict(list)
for line in open("/tmp/timing/host.txt"):
    m = re.match(r"round \d bin (\w+) K (\d+): wall\s*:\s*([\d.]+)", line)
    if m and m.group(1) == "sync":
        d[int(m.group(2))].append(float(m.group(3)))
print(min(d, key=lambda k: sum(d[k]) / len(d[k])) if d else 4)
PY
)
echo "best K (sync) $BEST" >> $T/summary.txt
run() {
  name=$1; k=$2; bin=$3
  REINGS_BIN=$bin timeout 100 python3 $P $k cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 - "$name" "$f" >> $T/summary.txt <<'PY'
import json, sys
name, f = sys.argv[1], sys.argv[2]
m = json.load(open(f))
s = m["seconds"]
print(name, round(m["mean"]["psnr"], 6), "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 2),
      {k: round(s[k], 2) for k in ("coarse", "fine", "final", "probes", "total")})
PY
  out
}
run K0_1 0 sync; run KB_1 $BEST sync; run KB_2 $BEST sync; run K0_2 0 sync; run KB_async $BEST async
out
cat $OUT/timing.txt
