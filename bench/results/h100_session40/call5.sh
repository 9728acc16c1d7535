set -u
# session 40, call 5: issue 15's point 2 with this tree (last measured in session 34, call 1: ratios 0.30-0.45): the
# training step against gsplat 1.5.3 on scenes A, B, C at SH 0 and 3, in one process, 3 rounds. No GPU step kernel's
# arithmetic changed since (session 39's project.cl switches are CPU-only; NVIDIA builds OpenCL's builtins).
# Predicted: every ratio <= 0.5, within +-0.05 of session 34's.
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
timeout 480 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
cat $OUT/peer_summary.txt $OUT/device.txt; head -2 $OUT/peer.txt
