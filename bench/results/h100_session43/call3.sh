set -u
# session 43, call 3: where scene C's step goes at SH 0 / 3 on the H200 (issue 15's point 2: C at SH 3 was the one
# ratio at 0.52, session 40), profiled per stage, no gsplat (its time is not needed for the breakdown).
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
REINGS_QUEUE_PROFILING=1 python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --no-gsplat --ref-crop -1 \
  --json $OUT/peer_prof.jsonl > $OUT/peer_prof.txt 2>&1
python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --no-gsplat --ref-crop -1 --no-breakdown \
  --json $OUT/peer_wall.jsonl > $OUT/peer_wall.txt 2>&1
cat $OUT/peer_prof.txt $OUT/peer_wall.txt | tail -40
