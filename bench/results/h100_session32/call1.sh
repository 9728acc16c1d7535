set -u
# session 32, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session32/call1.sh .gpu30
# The CPU-schedule change must leave the GPU schedule's bits alone: the rasterizer's and the builds' tests on NVIDIA,
# and fern at 3 views seed 0 full schedule as a user runs it (PSNR 22.330038 in sessions 28-31).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)|MHz"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 240 python3 -m pytest -q -x -p no:cacheprovider tests/test_rasterize.py tests/test_kernel_builds.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
/usr/bin/time -f "wall %e s" timeout 150 python3 -m reings.cli $EV --out $T/P1 > $T/P1.txt 2>&1
python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2), 'builds on clock', m.get('kernel_builds_on_clock'))" $T/P1/llff/reings/3views/fern/metrics.json > $OUT/fern.txt 2>&1
tail -2 $T/P1.txt >> $OUT/fern.txt
cat $OUT/fern.txt $OUT/device.txt
