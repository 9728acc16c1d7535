set -u
# issue 12, session 10: --stereo-seeds 0.1 on LLFF fern+flower at 3 views, seed 0, full schedule
# (2 runs sharing the GPU; the last minutes of the session's device time).
LIM=${1:-150}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --views 3 --methods reings --preset paper \
  --device cuda --no-lpips --gpu-only --scenes fern,flower --seeds 0 --stereo-seeds 0.1 --eval-every 0 --out /tmp/g/seeds3 \
  --cluster local:2 --runs-per-gpu 2 2>&1 | grep -v "^WARNING: Target" > /tmp/g/seeds3.log
echo "llff3 seeds $(( $(date +%s) - t0 )) s runs $(find /tmp/g -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
tail -5 /tmp/g/seeds3.log
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m['gaussians'].get('ehps'), m['gaussians'].get('final_prune'), m['seconds']['total'])"; done
