set -u
# session 13, call 3: GPU 1 runs runs3.txt's DTU lines at once (call_runs.sh, which packs /tmp/g at
# the end); GPU 0 runs fern at 3 views, seed 0, with the LLFF defaults, ONE RUN AT A TIME (issue 15's
# whole-run time): the defaults, then --soft-depth-shared, then the defaults with --profile.
D=bench/results/h100_session13
bash bench/results/h100_session11/call_runs.sh .gpu_c1 500 $D/runs3.txt > /tmp/dtu_call.txt 2>&1 &
sleep 20
for v in def:"" shared:"--soft-depth-shared" profile:"--profile"; do
  name=time_${v%%:*}; opts=${v#*:}
  REINGS_CACHE_DIR=/tmp/cache timeout 200 bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_c1/data/llff \
    --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips \
    --out /tmp/g/$name $opts 2>&1 | grep -v "^WARNING: Target" > /tmp/g/$name.log
  f=$(find /tmp/g/$name -name metrics.json); python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],3), {k: round(s[k],1) for k in ('coarse','fine','final','method','total')})"
done
wait
cat /tmp/dtu_call.txt
