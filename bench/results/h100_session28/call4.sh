set -u
# session 28, call 4 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session28/call4.sh
# Where reings' own Python goes in a GPU step: bench/bench_host.py (every pass on) wall, stubbed and cProfile.
R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
for m in wall stubbed wall; do timeout 100 python3 bench/bench_host.py --device cuda:0 --mode $m --iterations 601 --json $OUT/host.jsonl 2>&1 | grep -v "^WARNING" | tail -2; done > $OUT/host.txt
timeout 150 python3 bench/bench_host.py --device cuda:0 --mode cprofile --iterations 601 --top 80 --prof-out $OUT/cprofile.txt > /dev/null 2>&1
cat $OUT/host.txt; head -120 $OUT/cprofile.txt
