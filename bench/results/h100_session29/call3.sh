set -u
# session 29, call 3 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session29/call3.sh
# The session's code on NVIDIA: test_hard_depth_scale (the half-resolution hard pass; engines within float32 rounding
# there), test_device_fit, test_kernel_builds, test_rasterize.
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
REINGS_TEST_DEVICES=cuda timeout 540 python3 -m pytest -q tests/test_hard_depth_scale.py tests/test_device_fit.py tests/test_kernel_builds.py tests/test_rasterize.py -k "not oclgrind" -p no:cacheprovider 2>&1 | tail -6 > $OUT/tests.txt
cat $OUT/device.txt $OUT/tests.txt
