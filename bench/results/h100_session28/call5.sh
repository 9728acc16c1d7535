set -u
# session 28, call 5 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call5.sh .gpu_s24
# The session's final code on a fourth fresh host: fern 3v seed 0 full schedule four times in a row (the first with
# the on-disk caches empty), then the step against gsplat 1.5.3 on A, B, C at SH 0 and 3.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
run() {
  name=$1
  timeout 120 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'kernel_builds', m.get('kernel_builds'), 'on clock', [st.get('kernel_builds_on_clock') for st in m['stages'] if 'kernel_builds_on_clock' in st])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
run S1; run S2; run S3; run S4
timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
grep -E "training" $OUT/fern.txt; tail -25 $OUT/peer.txt
