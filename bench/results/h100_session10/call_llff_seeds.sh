set -u
# issue 12, session 10: EHPS seeded from the stereo prior (--stereo-seeds 0.1) on LLFF fern+flower
# at 2 views, seeds 0-2, full schedule; plus fern and flower 2 views seed 0 with the defaults (to check
# that this cache reproduces §12 to the last digit). 8 runs sharing the GPU; renders kept for LPIPS.
LIM=${1:-500}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
G="--dataset llff --root .gpu_llff/data/llff --views 2 --methods reings --preset paper --device cuda --no-lpips --gpu-only"
t0=$(date +%s)
(timeout $LIM bash scripts/lent_gpu.sh eval $G --scenes fern,flower --seeds 0 --out /tmp/g/base --cluster local:2 --runs-per-gpu 2 2>&1 | grep -v "^WARNING: Target" > /tmp/g/base.log) &
timeout $LIM bash scripts/lent_gpu.sh eval $G --scenes fern,flower --seeds 0,1,2 --stereo-seeds 0.1 --out /tmp/g/seeds \
  --cluster local:6 --runs-per-gpu 6 2>&1 | grep -v "^WARNING: Target" > /tmp/g/seeds.log
wait
echo "llff seeds $(( $(date +%s) - t0 )) s runs $(find /tmp/g -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print('$f'.split('/')[3], m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m['gaussians'].get('ehps'), m['gaussians'].get('final_prune'))"; done
