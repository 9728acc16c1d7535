set -u
# session 14, call 1: runs1.txt on both GPUs (call_runs.sh); carry .gpu_s13 (fern+flower images_8, SfM caches 2-4 views, stereo caches 3 views)
bash bench/results/h100_session11/call_runs.sh .gpu_s13 520 bench/results/h100_session14/runs1.txt
