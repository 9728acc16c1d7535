set -u
# issue 12, session 9: the stereo prior with SGM penalties 0.2 / 9.6 (was 0.03 / 0.6) and each view's
# near/far bounds as its depth range: DTU scan24 at 3 views (seeds 0, 1, 2) and 2, 4 views (seed 0), full schedule
# (5 runs sharing the GPU; DTU recipe, defaults). Renders kept (rescored here: scripts/rescore_dtu.py, LPIPS).
LIM=${1:-540}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_dtu/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
t0=$(date +%s)
G="--dataset dtu --root .gpu_dtu/data/dtu --scenes scan24 --methods reings --preset paper --device cuda --no-lpips --out /tmp/g/sgm"
(timeout $LIM bash scripts/lent_gpu.sh eval $G --views 2,4 --seeds 0 --cluster local:2 --runs-per-gpu 2 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/sgm24.log) &
timeout $LIM bash scripts/lent_gpu.sh eval $G --views 3 --seeds 0,1,2 --cluster local:3 --runs-per-gpu 3 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/sgm.log
wait
echo "sgm rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/sgm -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g/sgm -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), round(m['seconds'].get('train', 0) if isinstance(m['seconds'], dict) else m['seconds'],1))"; done
