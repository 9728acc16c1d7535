set -u
# session 29, call 2 (nvidia-h100-x1, call 1's host). Run from the repository root: bash bench/results/h100_session29/call2.sh .gpu29
# The step against gsplat 1.5.3 on A, B, C at SH 0 and 3 (call 1 ran out of time before it), then fern at 3 views,
# seed 0, full schedule, three runs alone (the session's code; GPU kernels unchanged since session 28).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing2; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
timeout 300 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
run() {
  name=$1
  timeout 100 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'on clock', [st.get('kernel_builds_on_clock') for st in m['stages'] if 'kernel_builds_on_clock' in st])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
run S1; run S2; run S3
python3 - > $OUT/peer_summary.txt <<'PY'
import json
for l in open('/tmp/peer_out/peer.jsonl' if False else __import__('os').environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
cat $OUT/peer_summary.txt; grep -E "training" $OUT/fern.txt
