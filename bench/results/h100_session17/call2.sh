set -u
# session 17, call 2: runs2.txt on both GPUs (call_runs.sh); carry .gpu_s20 (fern+flower images_8, NeX trex+room, SfM caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s20 530 bench/results/h100_session17/runs2.txt
