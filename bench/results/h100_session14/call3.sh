set -u
# session 14, call 3. GPU 1: runs3.txt's GPU-1 lines at once (call_runs.sh packs /tmp/g at the end).
# GPU 0, first ONE RUN AT A TIME (issue 15's whole-run time): fern, 3 views, seed 0, LLFF defaults,
# with the code before session 13's host changes (before/ = git archive 342f942) and with this tree;
# then bench_host.py on cuda:0 (wall, stubbed); then runs3.txt's GPU-0 lines.
D=bench/results/h100_session14
grep " 1 llff" $D/runs3.txt > /tmp/runs_gpu1.txt; grep " 0 llff" $D/runs3.txt > /tmp/runs_gpu0.txt
bash bench/results/h100_session11/call_runs.sh .gpu_s13 540 /tmp/runs_gpu1.txt > /tmp/gpu1_call.txt 2>&1 &
sleep 25
for v in before:before now:.; do
  name=time_${v%%:*}; root=${v#*:}
  (cd $root && REINGS_CACHE_DIR=/tmp/cache PYTHONPATH=/tmp/site:$PWD timeout 200 python3 -m reings.cli eval --dataset llff \
    --root $OLDPWD/.gpu_s13/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 \
    --no-lpips --out /tmp/g/$name 2>&1 | grep -v "^WARNING: Target" > /tmp/g/$name.log)
  f=$(find /tmp/g/$name -name metrics.json); python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],3), {k: round(s[k],1) for k in ('coarse','fine','final','method','total')})"
done
for mode in wall stubbed; do
  timeout 120 python3 bench/bench_host.py --device cuda:0 --mode $mode --label session14 --json /tmp/g/bench_host_cuda.jsonl.log 2>&1 | grep -v "^WARNING: Target" | tail -3 | tee -a /tmp/g/bench_host_cuda.log
done
# GPU 0's share of the sweep, then wait for GPU 1's (call_runs.sh's pack includes both: same /tmp/g)
bash bench/results/h100_session11/call_runs.sh .gpu_s13 300 /tmp/runs_gpu0.txt > /tmp/gpu0_call.txt 2>&1 &
wait
cat /tmp/gpu1_call.txt /tmp/gpu0_call.txt
