#!/usr/bin/env bash
# One batched run on the lent NVIDIA machine (see README "GPU"): NVIDIA OpenCL registered through
# OCL_ICD_VENDORS, the splatting-core tests on device "cuda", `reings bench` on cuda, and the gsplat
# peer in the same session. Wheels come from the git-ignored .whl/ folder (carry it).
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
python3 -m reings.cli devices | tee "$OUT/devices.txt"
CORE="tests/test_project.py tests/test_bin.py tests/test_sort.py tests/test_rasterize.py tests/test_render.py tests/test_hard_cases.py tests/test_losses.py"
REINGS_TEST_DEVICES=cuda timeout ${TEST_TIMEOUT:-300} python3 -m pytest -q -ra -p no:cacheprovider $CORE 2>&1 | tail -40 > "$OUT/pytest_cuda.txt"
tail -3 "$OUT/pytest_cuda.txt"
timeout ${BENCH_TIMEOUT:-150} python3 -m reings.cli bench --device cuda --out "$OUT/bench_cuda.jsonl" 2>&1 | tail -40 | tee "$OUT/bench_cuda.txt"
TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=16 timeout ${PEER_TIMEOUT:-150} python3 bench/peer_gsplat.py --json "$OUT/gsplat.jsonl" 2>&1 | tail -8
