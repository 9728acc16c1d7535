set -u
# session 44, call 4: the inline-exp tests (exp_inline, exp_splat) and the rasterizer's byte checks on NVIDIA's OpenCL
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q tests/test_rasterize.py -p no:cacheprovider -k "splat or inline_exp or io_and_builtins" 2>&1 | tail -4 > $OUT/tests.txt
cat $OUT/tests.txt
