set -u
# session 18, call 2: runs2.txt on four GPUs (call_runs.sh); carry .gpu_s23 (fern + flower, NeX room, DTU scan24 + masks, SfM caches, the stereo prior of fern + flower at 4 views and of scan24 at 3)
bash bench/results/h100_session11/call_runs.sh .gpu_s23 540 bench/results/h100_session18/runs2.txt
