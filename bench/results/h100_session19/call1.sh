set -u
# session 19, call 1 (nvidia-h100-x4). CARRY = $1 (.gpu_s26: fern + flower, DTU scan24 + masks, SfM caches,
# the stereo prior of fern + flower at 2 views, fern at 3, scan24 at 3).
# GPU 0 first, alone on its card while GPUs 1-3 train DTU: the kernel census of a whole fern 3-view run
# (bench/kernel_census.py), the same run plain (its wall clock), device_time.py --all; then GPU 0 trains
# the stereo 2-view cell. GPUs 1-3: runs1.txt's DTU lines.
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache /tmp/g /tmp/timing; cp -r $CARRY/cache/* /tmp/cache/
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
S=bench/results/h100_session19
grep -v " 0 llff " $S/runs1.txt > /tmp/runs_dtu.txt; grep "^#\| 0 llff " $S/runs1.txt > /tmp/runs_llff.txt
printf 'st2\n' > /tmp/g/pack_order.txt
(bash $S/call_runs_nopack.sh $CARRY 500 /tmp/runs_dtu.txt > /tmp/g/dtu_summary.txt 2>&1) &
T=/tmp/timing
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $T/timing.txt
timeout 120 python3 bench/kernel_census.py --out $T/census_fern3.json -- eval --dataset llff --root $CARRY/data/llff \
  --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/census 2>&1 \
  | grep -v "^WARNING: Target" > $T/census.log
timeout 120 bash scripts/lent_gpu.sh eval --dataset llff --root $CARRY/data/llff --scenes fern --views 3 --seeds 0 \
  --methods reings --preset paper --device cuda:0 --no-lpips --out $T/plain 2>&1 | grep -v "^WARNING: Target" > $T/plain.log
for f in $T/census/llff/reings/3views/fern/metrics.json $T/plain/llff/reings/3views/fern/metrics.json; do
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$f'.split('/')[3], round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))}, [(x['stage'], round(x['seconds'],1)) for x in m['stages']])" >> $T/timing.txt
done
timeout 90 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 --all 2>&1 | grep -v "^WARNING: Target" >> $T/timing.txt
tail -20 $T/census.log >> $T/timing.txt
cp -r $T /tmp/g/timing
bash $S/call_runs_nopack.sh $CARRY 320 /tmp/runs_llff.txt > /tmp/g/llff_summary.txt 2>&1
wait
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
cat /tmp/g/timing/timing.txt /tmp/g/dtu_summary.txt /tmp/g/llff_summary.txt
