set -u
# session 36, call 1. Run from the repository root: bash bench/results/h100_session36/call1.sh .gpu30
# Session 36's changes on NVIDIA: project.cl restructured around PROJ_BLOCK_IO (CPU-only blocks; the GPU's width-1 build
# keeps its loads and stores, now written through the IN_* / OUT_ROWS / GRAD_ROWS macros), view_warp's edge weights in
# their own kernel (view_warp_edges, once per training view), photometric.cl's SSIM_VW (CPU schedule only).
# 1: the GPU tests of the projection, the losses, view_warp, the drop and the device fit.
# 2: fern full schedule seeds 0 and 1 (the same bits predicted: 22.330038 / 22.301269, 25-28 s of training).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 330 python3 -m pytest -q -p no:cacheprovider tests/test_project.py tests/test_losses.py tests/test_view_warp.py tests/test_device_fit.py tests/test_drop.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 60 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for sd in 0 1; do
  timeout 100 python3 -m reings.cli $EV --seeds $sd --out $T/P$sd > $OUT/P$sd.txt 2>&1
  f=$(ls $T/P$sd/llff/reings/3views/*/metrics.json | head -1)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('seed', sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $f $sd | tee -a $OUT/fern.txt
done
cat $OUT/device.txt
