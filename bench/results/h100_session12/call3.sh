set -u
# session 12, call 3 (runs3.txt): per-run limit 500 s; the tree has the opacity-aware tile rect (bit-identical renders)
bash bench/results/h100_session11/call_runs.sh .gpu_s12b 500 bench/results/h100_session12/runs3.txt
