set -u
# session 19, call 3 (nvidia-h100-x4): runs3.txt (the 3-view ablation grid) on four GPUs; CARRY = $1 (.gpu_s27:
# fern + flower, SfM caches, the stereo prior of both at 3 views). The renders of every run are packed (LPIPS).
bash bench/results/h100_session11/call_runs.sh $1 545 bench/results/h100_session19/runs3.txt
