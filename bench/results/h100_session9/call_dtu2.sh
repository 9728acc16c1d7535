set -u
# issue 12, session 9: DTU scan24 at 2 views, full schedule, seeds 0-2: the DTU recipe's stereo
# settings (SGM 0.2 / 9.6, each view's near/far) against the LLFF ones (stereo:sgm_p1=0.03,sgm_p2=0.6),
# 6 runs sharing the GPU (two evals of 3). Renders kept (LPIPS rescored at home).
LIM=${1:-480}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_dtu/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
t0=$(date +%s)
G="--dataset dtu --root .gpu_dtu/data/dtu --scenes scan24 --views 2 --seeds 0,1,2 --methods reings --preset paper --device cuda --no-lpips --cluster local:3 --runs-per-gpu 3 --gpu-only"
(timeout $LIM bash scripts/lent_gpu.sh eval $G --out /tmp/g/dtu_sgm 2>&1 | grep -v "^WARNING: Target" > /tmp/g/dtu_sgm.log) &
timeout $LIM bash scripts/lent_gpu.sh eval $G --out /tmp/g/llff_sgm --depth-prior stereo:sgm_p1=0.03,sgm_p2=0.6 2>&1 | grep -v "^WARNING: Target" > /tmp/g/llff_sgm.log
wait
echo "rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print('$f'.split('/')[3], m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), m.get('depth_prior_options'))"; done
