set -u
# session 14, call 2: runs2.txt on both GPUs (call_runs.sh), from a copy of the working tree with the
# occlusion test (uncommitted at the time, committed after); carry .gpu_s14 (fern+flower images_8,
# DTU scan24 + masks, SfM caches, DTU's 3-view stereo caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s14 540 bench/results/h100_session14/runs2.txt
