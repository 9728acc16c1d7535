set -u
# issue 12, session 8, GPU call 3: the defaults (--depth-confidence 0) on LLFF fern+flower at 2 and 3 views, full
# schedule, seeds 0-2 (12 runs, 8 sharing the GPU: two waves). Renders kept for LPIPS (rescored here).
# The control of call 2, same machine kind and sharing; renders for LPIPS of the defaults.
LIM=${1:-540}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --scenes fern,flower --views 2,3 \
  --methods reings --seeds 0,1,2 --preset paper --device cuda --no-lpips --depth-confidence 0 \
  --out /tmp/g/default --cluster local:8 --runs-per-gpu 8 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/default.log
echo "default rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/default -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
cat /tmp/g/default/results.md 2>/dev/null | head -40
for f in $(find /tmp/g/default -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), round(m['seconds'].get('train', 0) if isinstance(m['seconds'], dict) else m['seconds'],1))"; done
