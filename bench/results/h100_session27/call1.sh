set -u
# session 27, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session27/call1.sh .gpu_s24
# (a) tests/test_sort.py on the GPU (onesweep's look-back with real concurrency); (b) the sort sweep, onesweep 0 / 1;
# (c) fern 3v seed 0 full schedule under host_wait, REINGS_SORT_ONESWEEP=1 (NEW) and =0 (OLD) alternating, three pairs;
# (d) peer_step A,B,C SH 0 / 3 (onesweep on), C with it off.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
python3 -c "import pyopencl as cl; d=[d for p in cl.get_platforms() for d in p.get_devices()][0]; print(d.name, d.version, d.local_mem_size); print(' '.join(sorted(d.extensions.split())))" >> $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q -x tests/test_sort.py -k "not oclgrind" -p no:cacheprovider > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
timeout 100 python3 bench/bench_sort_geometry.py --device cuda:0 --onesweep 0,1 --wgs 256 --bits 11 --repeats 30 --out $T/sweep.jsonl > $OUT/sweep.txt 2>&1; tail -12 $OUT/sweep.txt
run() {
  name=$1; os=$2
  REINGS_SORT_ONESWEEP=$os timeout 100 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
}
run new_1 1; run old_1 0; run new_2 1; run old_2 0; run new_3 1; run old_3 0
tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json *.jsonl)
timeout 110 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
REINGS_SORT_ONESWEEP=0 timeout 50 python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --rounds 3 --json $OUT/peer_off.jsonl > $OUT/peer_off.txt 2>&1
grep -A12 '^# ours' $OUT/peer.txt | head -13; grep -A6 '^# ours' $OUT/peer_off.txt | head -7; cat $OUT/fern.txt | grep training
