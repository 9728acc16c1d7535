set -u
# session 47, call 1: this session's CPU-schedule changes under NVIDIA's compiler (the tests build the CPU schedule
# there): rasterize_bwd's RASTER_BWD_SPLIT (the byte checks with the define on and off, the overflow cases), and
# project.cl's widths (skipped on GPUs: they run width 1)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > "$OUT/gpu.txt"
REINGS_TEST_DEVICES=cuda timeout 500 python3 -m pytest -q -p no:cacheprovider -n 4 tests/test_rasterize.py tests/test_project.py \
  -k "not oclgrind" 2>&1 | tail -6 > "$OUT/tests.txt"
cat "$OUT/gpu.txt" "$OUT/tests.txt"
