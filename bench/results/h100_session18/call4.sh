set -u
# session 18, call 4: runs4.txt on one GPU (call_runs.sh); carry .gpu_s25 (fern + flower, SfM caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s25 480 bench/results/h100_session18/runs4.txt
