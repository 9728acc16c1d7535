set -u
# session 43, call 4: Adam's loads first (adam.cl's adam_elem reads p, m, v before storing m and v: one memory round
# trip per element instead of two), A/B against the old adam.cl, alternating, scene C at SH 0 / 3, profiled and wall.
# Predicted: adam's device time at C SH 3 0.174 -> 0.12-0.14 ms; the wall step -0.03 to -0.05 ms.
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
for r in 1 2 3; do for v in new old; do
  cp .ab_s43/adam_$v.cl kernels/adam.cl
  REINGS_QUEUE_PROFILING=1 python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --no-gsplat --ref-crop -1 \
    --json $OUT/prof_$v.jsonl > /dev/null 2>&1
  python3 bench/peer_step.py --device cuda --scenes C,A --sh 3,0 --no-gsplat --ref-crop -1 --no-breakdown \
    --json $OUT/wall_$v.jsonl > /dev/null 2>&1
done; done
python3 - $OUT > $OUT/ab.txt <<'PY'
import json, sys, statistics as S
out = sys.argv[1]
for v in ("new", "old"):
    rows = [json.loads(l) for l in open(f"{out}/prof_{v}.jsonl")]
    for sh in (0, 3):
        r = [x for x in rows if x["sh"] == sh]
        print(v, "C sh", sh, "adam dev ms", [round(x["ours_dev_adam_ms"], 4) for x in r],
              "sum", [round(x["ours_dev_sum_ms"], 3) for x in r])
    rows = [json.loads(l) for l in open(f"{out}/wall_{v}.jsonl")]
    for sc in ("A", "C"):
        for sh in (0, 3):
            r = [x["ours_step_wall_ms"] for x in rows if x["sh"] == sh and x["scene"] == sc]
            print(v, sc, "sh", sh, "wall ms", [round(x, 4) for x in r], "median", round(S.median(r), 4))
PY
cat $OUT/ab.txt
