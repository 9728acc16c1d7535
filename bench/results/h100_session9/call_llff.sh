set -u
# issue 12, session 9: the stereo prior with SGM penalties 0.2 / 9.6 (was 0.03 / 0.6) and each view's
# near/far bounds as its depth range: LLFF fern+flower at 2 and 3 views, full schedule, seeds 0, 1
# (8 runs sharing the GPU). Same SfM cache as session 8 (fern 3v: 515 points). Renders kept for LPIPS.
LIM=${1:-540}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --scenes fern,flower --views 2,3 \
  --methods reings --seeds 0,1 --preset paper --device cuda --no-lpips \
  --out /tmp/g/sgm --cluster local:8 --runs-per-gpu 8 --gpu-only 2>&1 | grep -v "^WARNING: Target" > /tmp/g/sgm.log
echo "sgm rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/sgm -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g/sgm -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), round(m['seconds'].get('train', 0) if isinstance(m['seconds'], dict) else m['seconds'],1))"; done
