set -u
# session 17, call 1: runs1.txt on both GPUs (call_runs.sh); carry .gpu_s19 (fern+flower images_8, DTU scan24 + masks,
# SfM caches, stereo caches of fern/flower 3 views and DTU 3 views)
bash bench/results/h100_session11/call_runs.sh .gpu_s19 540 bench/results/h100_session17/runs1.txt
