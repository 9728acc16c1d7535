set -u
# phase a: prepare + serial + 1 GPU/3 PoCL; phase b: 4 GPU/2 PoCL, 6 GPU
mkdir -p /tmp/cache_q /tmp/g; cp -r --update=none .gpudata/cache_q/* /tmp/cache_q/
export REINGS_CACHE_DIR=/tmp/cache_q
R="bash scripts/lent_gpu.sh"
G="--dataset llff --root .gpudata/llff --scenes fern,flower --views 2,3,4 --methods reings,dngaussian --preset quick --no-lpips --device cuda"
t(){ local tag=$1 lim=$2; shift 2; local t0=$(date +%s%N); timeout $lim $R eval $G --out /tmp/g/$tag "$@" > /tmp/g/$tag.log 2>&1; echo "$tag rc=$? elapsed_ms $(( ($(date +%s%N) - t0) / 1000000 )) runs $(find /tmp/g/$tag -name metrics.json | wc -l)" | tee -a /tmp/g/summary.txt; pkill -9 -f multiprocessing.spawn; sleep 1; }
if [ "$1" = a ]; then
  nvidia-smi -L > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt; $R devices >> /tmp/g/machine.txt 2>&1
  # PoCL kernels compiled once before timing (the serial grid is NVIDIA only)
  (POCL_MAX_PTHREAD_COUNT=2 timeout 120 $R run --preset quick --iterations 2 --device pocl --out /tmp/warm > /tmp/g/warm.txt 2>&1 &)
  t0=$(date +%s); timeout 200 $R eval $G --out /tmp/prep --prepare-only > /tmp/g/prep.txt 2>&1; echo "prepare rc=$? $(( $(date +%s) - t0 )) s" | tee -a /tmp/g/summary.txt
  t serial 230
  t gpu1_pocl3 150 --cluster local:4
else
  t gpu4 90 --cluster local:4 --runs-per-gpu 4 --gpu-only
  t gpu8 90 --cluster local:8 --runs-per-gpu 8 --gpu-only
  t long_gpu6_pocl2 200 --seeds 0,1,2 --cluster local:8 --runs-per-gpu 6
  t long_gpu6 170 --seeds 0,1,2 --cluster local:6 --runs-per-gpu 6 --gpu-only
fi
cd /tmp/g && tar czf $OUT/grids_$1.tgz --exclude='*.png' --exclude='*.ply' --exclude=checkpoints --exclude=depths --exclude=renders .
