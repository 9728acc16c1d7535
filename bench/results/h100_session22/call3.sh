set -u
# session 22, call 3 (nvidia-h100-x1). Run from the repository root: bash call3.sh .gpu_s24
# Tree: HEAD with peer_step --rounds (.gpu_clean). (a) the training step against gsplat 1.5.3, the two sides
# alternating 5 times per configuration, unprofiled queue; (b) three fern 3v seed 0 full runs (the
# training time's spread on one host).
CARRY=$1; R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/summary.txt 2>/dev/null; tail -25 $T/peer.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
timeout 330 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 5 --json $OUT/peer_rounds.jsonl > $T/peer.txt 2>&1
cp $T/peer.txt $OUT/; out
run() {
  name=$1
  timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern \
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
run NEW_1; run NEW_2; run NEW_3
out
cat $OUT/timing.txt
