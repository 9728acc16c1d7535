set -u
# session 16, call 3: GPU 1 runs runs3.txt (call_runs.sh, in the background); GPU 0 times sync vs sync-free binning
# (call3_timing.sh, results in /tmp/timing -> $OUT/timing.tgz). Carry .gpu_s18 (.gpu_s14 + fern's 3-view stereo caches).
(bash bench/results/h100_session11/call_runs.sh .gpu_s18 500 bench/results/h100_session16/runs3.txt > /tmp/runs3.out 2>&1) &
sleep 20  # call_runs.sh installs the wheels and fills /tmp/cache first
bash bench/results/h100_session16/call3_timing.sh .gpu_s18
tar czf $OUT/timing.tgz -C /tmp timing
cat /tmp/timing/*.txt
wait
cat /tmp/runs3.out
