set -u
# session 15, call 1: runs1.txt on both GPUs (call_runs.sh); carry .gpu_s14 (fern+flower images_8,
# DTU scan24 + masks, SfM caches, DTU's 3-view stereo caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s14 560 bench/results/h100_session15/runs1.txt
