set -u
# session 20, call 5 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24).
# (a) bench_rasterize on scene A (100k Gaussians) with the GPU schedule's batch sizes varied (FWD_BATCH, BWD_BATCH:
#     the same bits: the per-Gaussian sums do not depend on them); (b) a fern 3v run with --profile (the wall
#     seconds of every phase, the queue finished around each: where the non-kernel time goes).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/raster.txt $T/phases.txt 2>/dev/null; } > $OUT/timing.txt; }
for fb in 256,32 256,16 256,64 128,32 64,32 256,32; do
  f=${fb%,*}; b=${fb#*,}
  echo "FWD_BATCH=$f BWD_BATCH=$b" >> $T/raster.txt
  timeout 90 python3 bench/bench_rasterize.py --device cuda:0 --scene A --runs 40 --no-count --define FWD_BATCH=$f --define BWD_BATCH=$b 2>&1 | grep -v "^WARNING: Target" | grep "^  " >> $T/raster.txt
  out
done
timeout 120 python3 -m reings.cli eval --dataset llff --root $CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --profile --out $T/prof > $T/prof.log 2>&1
python3 - >> $T/phases.txt <<'PY'
import json
m = json.load(open("/tmp/timing/prof/llff/reings/3views/fern/metrics.json"))
print("psnr", m["mean"]["psnr"], "seconds", {k: round(v, 2) for k, v in m["seconds"].items() if isinstance(v, (int, float))})
for st in m.get("stages", []):
    ph = st.get("phases")
    if ph:
        print(st.get("name", st.get("stage")), {k: round(v, 3) for k, v in sorted(ph.items(), key=lambda kv: -kv[1]) if isinstance(v, (int, float))})
PY
out
cat $OUT/timing.txt
