set -u
# session 28, call 7 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call7.sh .gpu_s24
# The sync-free binning against the sync default with today's code (onesweep, SSIM pairs, builds off the clock):
# fern 3v seed 0 full schedule under host_wait, REINGS_BIN=sync / async alternating, a warm-up run first.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
run() {
  name=$1; mode=$2
  REINGS_BIN=$mode timeout 120 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', '$mode', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'binning', m['memory']['binning'])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
run W0 sync; run S1 sync; run A1 async; run S2 sync; run A2 async; run S3 sync; run A3 async
grep -E "training" $OUT/fern.txt
