set -u
# session 22, call 4 (nvidia-h100-x1). Run from the repository root: bash call4.sh .gpu_s24
# Tree: HEAD (.gpu_clean): project.cl's SH rows staged through local memory on the GPU schedule (PROJ_SH_STAGE).
# (a) the projection / fit tests on NVIDIA; (b) peer_step --rounds 5 (staged, the default), then B and C at SH 3
# with REINGS_PROJ_STAGE=0, interleaved rounds 3; (c) profiled C SH 3 both ways (project_fwd / project_bwd device
# time); (d) one fern run (PSNR unchanged).
CARRY=$1; R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PYTHONPATH=/tmp/site:$S PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/summary.txt 2>/dev/null; for f in peer_stage peer_nostage; do grep -A8 '^# ours' $T/$f.txt 2>/dev/null | head -9; done; grep -h 'device ms C-sh3' $T/prof_*.txt 2>/dev/null; } > $OUT/timing.txt; }
cd $S
(REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q tests/test_project.py tests/test_device_fit.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
out
timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 5 --json $OUT/peer_stage.jsonl > $T/peer_stage.txt 2>&1; out
REINGS_PROJ_STAGE=0 timeout 100 python3 bench/peer_step.py --device cuda --scenes B,C --sh 3 --rounds 3 --json $OUT/peer_nostage.jsonl > $T/peer_nostage.txt 2>&1; out
for st in 1 0; do
  REINGS_PROJ_STAGE=$st REINGS_QUEUE_PROFILING=1 timeout 60 python3 bench/peer_step.py --device cuda --scenes C --sh 3 --no-gsplat --ref-crop -1 > $T/prof_$st.txt 2>&1
  sed -i "s/device ms C-sh3/device ms C-sh3 (REINGS_PROJ_STAGE=$st)/" $T/prof_$st.txt; out
done
timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 \
  --methods reings --preset paper --device cuda:0 --no-lpips --out $T/fern 2>&1 | grep -v "^WARNING: Target" > $T/fern.log
python3 - >> $T/summary.txt <<'PY'
import json
m = json.load(open("/tmp/timing/fern/llff/reings/3views/fern/metrics.json"))
s = m["seconds"]
print("fern", round(m["mean"]["psnr"], 6), "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 2),
      {k: round(s[k], 2) for k in ("coarse", "fine", "final", "probes", "total")})
PY
cp $T/peer_*.txt $T/prof_*.txt $OUT/; out
cat $OUT/timing.txt
