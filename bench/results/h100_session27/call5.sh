set -u
# session 27, call 5 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session27/call5.sh .gpu_s24
# After the review fixes: (a) tests/test_device_fit.py and the photometric tests on the GPU; (b) fern 3v seed 0 full
# schedule under host_wait with the defaults, three runs in a row on a fresh host (is the first run slower?).
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
run() {
  name=$1; shift
  env "$@" timeout 100 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
run A_1 REINGS_SORT_ONESWEEP=1; run A_2 REINGS_SORT_ONESWEEP=1; run A_3 REINGS_SORT_ONESWEEP=1
REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q tests/test_device_fit.py tests/test_losses.py -k "not oclgrind" -p no:cacheprovider 2>&1 | tail -4 > $OUT/tests.txt; cat $OUT/tests.txt
grep -E "training|launches" $OUT/fern.txt | grep -v other
