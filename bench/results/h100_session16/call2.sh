set -u
# session 16, call 2: runs2.txt on both GPUs (call_runs.sh); carry .gpu_s14 (fern+flower images_8, DTU scan24 + masks,
# SfM caches, DTU's 3-view stereo caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s14 530 bench/results/h100_session16/runs2.txt
