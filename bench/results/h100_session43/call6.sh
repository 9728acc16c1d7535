set -u
# session 43, call 6: issue 15's point 2 with this tree (ADAM_LOADS_FIRST on GPUs; session 40, call 5: A 0.368 / 0.392,
# B 0.347 / 0.367, C 0.417 / 0.520 at SH 0 / 3): the step against gsplat 1.5.3, scenes A, B, C at SH 0 and 3, one
# process, 3 rounds; first the Adam tests on the GPU (the loads-first build against the numpy twin, bit for bit).
# Predicted: every ratio within +-0.05 of session 40's; C at SH 3 ours ~0.02 ms faster (call 4-5's device time), its
# ratio still set by gsplat's time in the process (2.2-3.4 ms across sessions).
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q -p no:cacheprovider tests/test_adam.py tests/test_adam_kernel.py \
  tests/test_adam_multi.py -k "not oclgrind" > $OUT/tests.txt 2>&1
tail -3 $OUT/tests.txt
timeout 420 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']],
              'ours adam dev', round(d.get('ours_dev_adam_ms', float('nan')), 4))
PY
cat $OUT/peer_summary.txt $OUT/device.txt; head -2 $OUT/peer.txt
