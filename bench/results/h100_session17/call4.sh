set -u
# session 17, call 4: runs4.txt, 2 runs per GPU (call_runs.sh); carry .gpu_s21 (NeX trex + room, SfM caches, their
# 3-view stereo caches)
bash bench/results/h100_session11/call_runs.sh .gpu_s21 185 bench/results/h100_session17/runs4.txt
