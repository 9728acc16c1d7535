set -u
# session 22, call 6 (nvidia-h100-x1). Run from the repository root: bash call6.sh
# Tree: HEAD (.gpu_clean): the staged SH copy in two branch-free loops. (a) the projection tests on NVIDIA;
# (b) the profiled C SH 3 breakdown with and without staging; (c) peer_step --rounds 5, all scenes.
R=$PWD; S=$R/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
export PYTHONPATH=/tmp/site:$S PATH=/tmp/site/bin:$PATH PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt 2>/dev/null; grep -h 'device ms C-sh3' $T/prof_*.txt 2>/dev/null; grep -A8 '^# ours' $T/peer.txt 2>/dev/null | head -9; } > $OUT/timing.txt; }
cd $S
(REINGS_TEST_DEVICES=cuda timeout 120 python3 -m pytest -q tests/test_project.py tests/test_device_fit.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
out
for st in 1 0; do
  REINGS_PROJ_STAGE=$st REINGS_QUEUE_PROFILING=1 timeout 60 python3 bench/peer_step.py --device cuda --scenes C --sh 3 --no-gsplat --ref-crop -1 > $T/prof_$st.txt 2>&1
  sed -i "s/device ms C-sh3/device ms C-sh3 (REINGS_PROJ_STAGE=$st)/" $T/prof_$st.txt; out
done
timeout 220 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 5 --json $OUT/peer.jsonl > $T/peer.txt 2>&1
cp $T/peer.txt $T/prof_*.txt $OUT/; out
cat $OUT/timing.txt
