set -u
# session 28, call 3 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call3.sh .gpu_s24
# (a) Why is a fresh host's first fern run slower (builds are off the clock now)? Three fern runs in a row under
# bench/host_wait.py (per stage: launches, the driver's enqueue us per launch, seconds blocked), the GPU's clocks and
# performance state before, between and after; (b) sort.cl's block_sort / block_scatter on NVIDIA: test_sort, PSNR.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version,persistence_mode --format=csv,noheader > $OUT/device.txt
gpu() { echo "== $1 $(date +%T)"; nvidia-smi --query-gpu=pstate,clocks.sm,clocks.mem,clocks.max.sm,power.draw,temperature.gpu --format=csv,noheader; }
gpu start >> $OUT/device.txt
run() {
  name=$1
  timeout 120 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'load/prior/sfm', [round(s[k],2) for k in ('load','depth_prior','sfm')])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
  gpu "after $name" >> $OUT/device.txt
}
run R1; run R2; run R3
REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_sort.py -k "not oclgrind" -p no:cacheprovider 2>&1 | tail -3 > $OUT/tests.txt; cat $OUT/tests.txt
cat $OUT/device.txt; grep -E "training|coarse|fine|final" $OUT/fern.txt | head -40
