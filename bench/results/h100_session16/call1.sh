set -u
# session 16, call 1: runs1.txt on both GPUs (call_runs.sh); carry .gpu_s17 (NeX trex + room, DTU scan24 + masks,
# SfM caches for both, DTU's 3-view stereo caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s17 530 bench/results/h100_session16/runs1.txt
