set -u
# session 39, call 1: NVIDIA builds of this session's kernels (REINGS_SCALAR_BUILTINS off there: OpenCL's builtins;
# view_warp's per-pixel kernels and view_warp_rows before the gather; project_bwd_opacity) through the kernel tests,
# then fern at 3 views, seeds 0-2, one run at a time (the full schedule, the default settings): the training seconds
# of a lone run (session 37: 26.5 s) and the PSNR against session 38's runs of the same default (call 3, 'area':
# 22.3598 / 22.2314 / 22.1712, two runs at a time). Predicted: tests pass; the PSNR digits equal (no value changed).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -p no:cacheprovider tests/test_view_warp.py tests/test_view_warp_fit.py \
  tests/test_project.py tests/test_depth_loss_kernel.py tests/test_adam_kernel.py tests/test_adam_multi.py tests/test_device_fit.py \
  tests/test_scalar_builtins.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
T=/tmp/runs; mkdir -p $T
for s in 0 1 2; do
  timeout 120 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds $s \
    --methods reings --preset paper --device cuda:0 --no-lpips --out $T > $T/fern_$s.txt 2>&1
  d=fern; [ $s != 0 ] && d=fern_seed$s
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(m['scene'], m['seed'], repr(m['mean']['psnr']), round(m['mean']['ssim'],4), 'training', round(sum(s[k] for k in ('coarse','fine','final')),1), 'total', round(s['total'],1), m['gaussians']['final_prune'])" $T/llff/reings/3views/$d/metrics.json >> $OUT/fern.txt
done
cat $OUT/fern.txt
