set -u
# session 31, call 3 (nvidia-h100-x1): our training step on scenes A, B, C at SH 0 / 3, profiled per stage (the device
# breakdown of a C step: what a robust 0.5x against gsplat would have to cut). Run: bash bench/results/h100_session31/call3.sh
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
REINGS_QUEUE_PROFILING=1 timeout 300 python3 bench/peer_step.py --device cuda --scenes A,C --sh 0,3 --no-gsplat --rounds 1 --json $OUT/peer_prof.jsonl > $OUT/peer_prof.txt 2>&1
tail -30 $OUT/peer_prof.txt
