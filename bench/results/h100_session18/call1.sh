set -u
# session 18, call 1: runs1.txt on four GPUs (call_runs.sh); carry .gpu_s22 (fern + flower images, NeX trex, SfM caches, the stereo prior of fern + flower at 2 views)
bash bench/results/h100_session11/call_runs.sh .gpu_s22 540 bench/results/h100_session18/runs1.txt
