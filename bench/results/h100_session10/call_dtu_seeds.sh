set -u
# issue 12, session 10: EHPS plus points seeded from the stereo prior's confident pixels
# (--stereo-seeds F): DTU scan24, full schedule, N runs sharing the GPU (one eval).
# usage: bash call_dtu_seeds.sh LIMIT VIEWS SEEDS "EXTRA OPTIONS" [NAME]
LIM=${1:-540}; VIEWS=${2:-2,3,4}; SEEDS=${3:-0,1,2}; EXTRA=${4:---stereo-seeds 0.1}; NAME=${5:-seeds}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_dtu/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
N=$(( $(echo $VIEWS | tr ',' '\n' | wc -l) * $(echo $SEEDS | tr ',' '\n' | wc -l) ))
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset dtu --root .gpu_dtu/data/dtu --scenes scan24 --views $VIEWS \
  --seeds $SEEDS --methods reings --preset paper --device cuda --no-lpips --cluster local:$N --runs-per-gpu $N \
  --gpu-only --out /tmp/g/$NAME $EXTRA 2>&1 | grep -v "^WARNING: Target" > /tmp/g/$NAME.log
echo "$NAME rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/$NAME -name metrics.json | wc -l)" | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
for f in $(find /tmp/g -name metrics.json); do python3 -c "import json,sys; m=json.load(open('$f')); print(m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4), round(m['seconds']['train'],1), m['gaussians'])"; done
