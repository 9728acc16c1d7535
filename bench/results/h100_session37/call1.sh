set -u
# session 37, call 1: rasterize.cl's kernels gained arguments in both schedules (RASTER_HITS' sets; the GPU schedule
# ignores them); the rasterizer, projection, device-fit, drop and render tests on NVIDIA and fern seeds 0 and 1
# (predicted: all pass; the digits of session 36, 22.330038 / 22.301269, in 25-30 s of training each).
# Run from the repository root: bash bench/results/h100_session37/call1.sh .gpu30
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
REINGS_TEST_DEVICES=cuda timeout 330 python3 -m pytest -q -p no:cacheprovider tests/test_rasterize.py tests/test_project.py tests/test_device_fit.py tests/test_drop.py tests/test_render.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 60 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for s in 0 1; do
  timeout 100 python3 -m reings.cli $EV --seeds $s --out $T/P$s > $OUT/P$s.txt 2>&1
  f=$(ls $T/P$s/llff/reings/3views/*/metrics.json | head -1)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('seed', sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $f $s | tee -a $OUT/fern.txt
done
