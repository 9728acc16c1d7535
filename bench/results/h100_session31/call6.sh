set -u
# session 31, call 6 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session31/call6.sh .old31
# Steady-state ms per iteration of bench_host's all-passes iteration (504 x 378, 30k Gaussians, SH 1; hard + soft depth,
# photometric + view_warp, DropGaussian; no densification) on the GPU, three variants alternating in separate processes
# six times: OLD (03b1ab8), NEW (this tree), NEW with the depth loss unfused (REINGS_DL_FUSE=0).
OLDT=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONUNBUFFERED=1
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; } > $OUT/device.txt 2>&1
for k in 0 1 2 3 4 5 6; do
  for v in OLD NEW NEWSEP; do
    src=$R; [ $v = OLD ] && src=$R/$OLDT
    fuse=1; [ $v = NEWSEP ] && fuse=0
    (cd $src && REINGS_DL_FUSE=$fuse PYTHONPATH=/tmp/site:$src timeout 60 python3 bench/bench_host.py --device cuda:0 --mode wall \
       --iterations 401 --warmup 3 --label $v$k --json $OUT/host.jsonl 2>&1 | grep -E "^wall" >> $OUT/host.txt)
  done
done
python3 - > $OUT/summary.txt <<'PY'
import json, os, statistics as st
rows = [json.loads(l) for l in open(os.environ['OUT'] + '/host.jsonl')]
by = {}
for r in rows:
    k = int(r['label'][-1]); v = r['label'][:-1]
    if k == 0: continue  # round 0 warms the kernel caches
    by.setdefault(v, []).append(r['ms_per_iteration'])
for v, xs in by.items():
    print(v, 'ms/it median %.3f' % st.median(xs), 'runs', [round(x, 3) for x in xs], 'losses', sorted({r['final_loss'] for r in rows if r['label'][:-1] == v}))
PY
cat $OUT/summary.txt $OUT/device.txt
