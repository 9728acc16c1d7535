set -u
# issue 12, session 8, GPU call 2: --depth-confidence 1 on LLFF fern+flower at 2 and 3 views, full
# schedule, seeds 0-2 (12 runs, 8 sharing the GPU: two waves). Renders kept for LPIPS (rescored here).
# Call 1 (call1.sh: 19 runs in three concurrent evals) finished no run in 530 s: one GPU shared by 19
# runs gave about 2x the serial throughput, not the 3x of 12 (docs/results.md §11).
LIM=${1:-540}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --scenes fern,flower --views 2,3 \
  --methods reings --seeds 0,1,2 --preset paper --device cuda --no-lpips --depth-confidence 1 \
  --out /tmp/g/conf1 --cluster local:8 --runs-per-gpu 8 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/conf1.log
echo "conf1 rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/conf1 -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
cat /tmp/g/conf1/results.md 2>/dev/null | head -40
for f in $(find /tmp/g/conf1 -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), round(m['seconds'].get('train', 0) if isinstance(m['seconds'], dict) else m['seconds'],1))"; done
