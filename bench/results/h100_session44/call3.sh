set -u
# session 44, call 3: the rasterizer's tests on NVIDIA's OpenCL (the CPU schedule's new defines compile there with
# their library forms; the inline exp, forced on, against float64 to 1 ulp)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
REINGS_TEST_DEVICES=cuda timeout 500 python3 -m pytest -q tests/test_rasterize.py -p no:cacheprovider -k "not oclgrind" 2>&1 | tail -15 > $OUT/tests.txt
cat $OUT/tests.txt
