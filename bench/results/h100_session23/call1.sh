set -u
# session 23, call 1 (nvidia-h100-x1). Run from the repository root: bash call1.sh .gpu_s24
# OLD = 9249c82 (.gpu_old); NEW = the transposed warp sum in rasterize_bwd (.gpu_clean, RASTER_BWD_TRANSPOSE=1).
# (a) the rasterizer tests on NVIDIA (the new bit test: records of TRANSPOSE 0 and 1 byte for byte);
# (b) bench_rasterize A / C: rasterize_bwd device ms with TRANSPOSE 0, 1, and 1 with BWD_BATCH=64;
# (c) peer_step --rounds 5, all scenes; (d) fern 3v seed 0 full schedule OLD, NEW, NEW, OLD.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/rast.txt 2>/dev/null; grep -A8 '^# ours' $T/peer.txt 2>/dev/null | head -9; cat $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$R/.gpu_old";; *) echo "$R/.gpu_clean";; esac; }
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD REINGS_TEST_DEVICES=cuda timeout 240 python3 -m pytest -q tests/test_rasterize.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -3) > $T/tests.txt
out
for sc in A C; do
  for d in "RASTER_BWD_TRANSPOSE=0" "RASTER_BWD_TRANSPOSE=1" "RASTER_BWD_TRANSPOSE=0" "RASTER_BWD_TRANSPOSE=1" "BWD_BATCH=64"; do
    (cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD timeout 60 python3 bench/bench_rasterize.py --device cuda:0 --scene $sc --no-count --define $d 2>&1 \
      | grep -E "^  (fwd |bwd |reduce)" | tr -s ' ' | tr '\n' ' ' | sed "s/^/$sc $d: /"; echo) >> $T/rast.txt
  done
  out
done
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD timeout 220 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 5 --json $OUT/peer.jsonl > $T/peer.txt 2>&1)
out
run() {
  name=$1; s=$(src $2); shift 2
  (cd $s && PYTHONPATH=/tmp/site:$s timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name "$@" 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 - "$name" "$f" >> $T/summary.txt <<'PY'
import json, sys
name, f = sys.argv[1], sys.argv[2]
m = json.load(open(f))
s = m["seconds"]
tr = sum(s[k] for k in ("coarse", "fine", "final"))
print(name, round(m["mean"]["psnr"], 6), "training", round(tr, 2), {k: round(v, 2) for k, v in s.items() if isinstance(v, (int, float))})
PY
  out
}
run OLD_1 OLD; run NEW_1 NEW; run NEW_2 NEW; run OLD_2 OLD
cp $T/peer.txt $T/*.log $OUT/ 2>/dev/null
out
cat $OUT/timing.txt
