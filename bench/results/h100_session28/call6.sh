set -u
# session 28, call 6 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call6.sh
# The final code's GPU tests: test_rasterize (the byte tests' shared helper, the transposed warp sum), test_kernel_builds
# (the clock test at every variant), test_device_fit, test_sort.
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
REINGS_TEST_DEVICES=cuda timeout 500 python3 -m pytest -q tests/test_rasterize.py tests/test_kernel_builds.py tests/test_device_fit.py tests/test_sort.py -k "not oclgrind" -p no:cacheprovider 2>&1 | tail -5 > $OUT/tests.txt
cat $OUT/device.txt $OUT/tests.txt
