set -u
# session 19, call 5 (nvidia-h100-x4): runs5.txt on four GPUs; CARRY = $1 (.gpu_s28: DTU scan24 + masks, SfM caches,
# the stereo prior of scan24 at 2, 3 and 4 views). Renders of the 2- and 4-view runs packed first (LPIPS).
mkdir -p /tmp/g; printf 'dtu2\ndtu4\n' > /tmp/g/pack_order.txt
bash bench/results/h100_session11/call_runs.sh $1 540 bench/results/h100_session19/runs5.txt
