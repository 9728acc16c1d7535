set -u
# issue 12, session 10: DTU scan24, full schedule, defaults after the stereo-box fallback (2 views:
# SfM finds no points, so the box and EHPS seeds come from the stereo prior), with the prune curve
# (test PSNR of the final model cut to its top 100..40 % by training-view Omega_G; reporting only).
# 8 runs sharing the GPU: views 2, 3 x seeds 0-2 and views 4 x seeds 0, 1.
LIM=${1:-550}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_dtu/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
G="--dataset dtu --root .gpu_dtu/data/dtu --scenes scan24 --methods reings --preset paper --device cuda --no-lpips --prune-curve --out /tmp/g/box"
t0=$(date +%s)
(timeout $LIM bash scripts/lent_gpu.sh eval $G --views 4 --seeds 0,1 --cluster local:2 --runs-per-gpu 2 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/box4.log) &
timeout $LIM bash scripts/lent_gpu.sh eval $G --views 2,3 --seeds 0,1,2 --cluster local:6 --runs-per-gpu 6 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/box23.log
wait
echo "box $(( $(date +%s) - t0 )) s runs $(find /tmp/g/box -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m['sfm']['method'], [(p['keep'], round(p['psnr'],2)) for p in m.get('prune_curve', [])])"; done
