set -u
# session 25, call 4 (nvidia-h100-x1). Run from the repository root: bash call4.sh
# Where scene C's step goes at SH 0 and SH 3 (issue 15's last step ratio above 0.5): peer_step without gsplat, with
# the queue's profiling (per-stage device ms), SH rows staged (the default) and not (REINGS_PROJ_STAGE=0); then the
# same two without profiling (wall).
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
export PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $T/machine.txt
cd .gpu_clean
for st in 1 0; do
  REINGS_PROJ_STAGE=$st REINGS_QUEUE_PROFILING=1 PYTHONPATH=/tmp/site:$PWD timeout 120 python3 bench/peer_step.py --device cuda \
    --scenes C --sh 0,3 --no-gsplat --ref-crop -1 --json $T/prof_stage$st.jsonl > $T/prof_stage$st.txt 2>&1
  REINGS_PROJ_STAGE=$st PYTHONPATH=/tmp/site:$PWD timeout 120 python3 bench/peer_step.py --device cuda \
    --scenes C --sh 0,3 --no-gsplat --ref-crop -1 --no-breakdown --rounds 3 --json $T/wall_stage$st.jsonl > $T/wall_stage$st.txt 2>&1
done
python3 - $T <<'PY' > $T/summary.txt
import json, sys, glob, os
for f in sorted(glob.glob(sys.argv[1] + "/*.jsonl")):
    for l in open(f):
        d = json.loads(l)
        if d.get("kind") != "step":
            continue
        dev = {k[8:-3]: round(v, 4) for k, v in d.items() if k.startswith("ours_dev_") and k.endswith("_ms")}
        print(os.path.basename(f), "SH", d["sh"], "wall", round(d["ours_step_wall_ms"], 3), "host_enqueue",
              round(d["ours_step_host_enqueue_ms"], 3), dev)
PY
cp $T/*.txt $OUT/
cat $T/machine.txt $T/summary.txt
