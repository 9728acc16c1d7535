set -u
# session 36, call 4: the final re-read touched project.cl's GPU build once more (SH_ROWS_ZERO through an array of zeros); as call 3 (the v_proj loads and the SH gradient
# stores through one code path with a constant blk = 0); the projection, device-fit and drop tests on NVIDIA and fern
# seed 0 (predicted: all pass; 22.330038 in 25-30 s of training).
# Run from the repository root: bash bench/results/h100_session36/call4.sh .gpu30
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing4; mkdir -p $T
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -p no:cacheprovider tests/test_project.py tests/test_device_fit.py tests/test_drop.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 60 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
timeout 100 python3 -m reings.cli $EV --seeds 0 --out $T/P0 > $OUT/P0.txt 2>&1
f=$(ls $T/P0/llff/reings/3views/*/metrics.json | head -1)
python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('seed 0', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $f | tee -a $OUT/fern.txt
