set -u
# session 33, call 5 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session33/call5.sh .gpu30
# BWD_BATCH 64 by default (call 1: bwd 0.983 / 0.976 of 32 on A / C): the records keep their bytes on NVIDIA's shuffle
# path (tests), and fern seed 0 keeps PSNR 22.330038.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing5; mkdir -p $T
REINGS_TEST_DEVICES=cuda timeout 100 python3 -m pytest -q -x -p no:cacheprovider tests/test_rasterize.py -k "batch_keeps or transposed or bwd_matches" > $OUT/tests.txt 2>&1; tail -1 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 60 python3 -m reings.cli $EV --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
timeout 80 python3 -m reings.cli $EV --out $T/P > $T/P.txt 2>&1
python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $T/P/llff/reings/3views/fern/metrics.json | tee $OUT/fern.txt
