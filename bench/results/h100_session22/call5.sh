set -u
# session 22, call 5 (nvidia-h100-x1). Run from the repository root: bash call5.sh .gpu_s24
# Tree: eee3ac4 (.gpu_clean): project.cl reads sh_dc / sh_rest in place (no sh_pack), the review's fixes.
# (a) tests on NVIDIA; (b) peer_step --rounds 5, and the profiled C SH 3 breakdown; (c) two fern runs.
CARRY=$1; R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/summary.txt 2>/dev/null; grep -A8 '^# ours' $T/peer.txt 2>/dev/null | head -9; grep -h 'device ms C-sh3' $T/prof.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
(REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_project.py tests/test_apply_rows.py tests/test_device_fit.py tests/test_adam_multi.py tests/test_prune_unseen.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
out
timeout 220 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 5 --json $OUT/peer.jsonl > $T/peer.txt 2>&1; out
REINGS_QUEUE_PROFILING=1 timeout 60 python3 bench/peer_step.py --device cuda --scenes C --sh 3 --no-gsplat --ref-crop -1 > $T/prof.txt 2>&1; out
for name in fern_1 fern_2; do
  timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 \
    --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" > $T/$name.log
  python3 - $name >> $T/summary.txt <<'PY'
import json, sys
m = json.load(open(f"/tmp/timing/{sys.argv[1]}/llff/reings/3views/fern/metrics.json"))
s = m["seconds"]
print(sys.argv[1], round(m["mean"]["psnr"], 6), "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 2),
      {k: round(s[k], 2) for k in ("coarse", "fine", "final", "probes", "total")})
PY
  out
done
cp $T/peer.txt $T/prof.txt $OUT/; out
cat $OUT/timing.txt
