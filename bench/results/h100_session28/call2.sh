set -u
# session 28, call 2 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call2.sh .gpu_s24
# train.fit builds its programs before its clock (OpenCLBackend.prepare): fern 3v seed 0 full schedule, cold (the
# on-disk caches cleared) and warm alternating, three of each on one fresh host, every build recorded; GPU tests.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
clear_caches() { rm -rf ~/.cache/pyopencl* ~/.nv/ComputeCache; }
fern() {
  name=$1
  timeout 120 python3 bench/bench_builds.py record --out $T/rec_$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -3 > $T/f_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'coarse/fine/final', [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'kernel_builds', m.get('kernel_builds'), [(st['stage'], st.get('kernel_builds'), st.get('kernel_builds_on_clock')) for st in m['stages'] if 'kernel_builds' in st])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/f_$name.txt 2>&1
  for f in $T/f_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/records.tgz -C $T $(cd $T && ls *.json)
}
clear_caches; fern cold1; fern warm1; clear_caches; fern cold2; fern warm2; clear_caches; fern cold3; fern warm3
REINGS_TEST_DEVICES=cuda timeout 240 python3 -m pytest -q tests/test_kernel_builds.py tests/test_device_fit.py -k "not oclgrind" -p no:cacheprovider 2>&1 | tail -4 > $OUT/tests.txt; cat $OUT/tests.txt
grep -E "training" $OUT/fern.txt
