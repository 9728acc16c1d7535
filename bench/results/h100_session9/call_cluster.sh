# issue 16: serial `reings eval` and one GPU worker + 3 PoCL workers (list scheduling 4b6a863, malloc fix 445e59a), the same quick grid, one machine
# (carry .whl and .gpu_llff: data/llff + the 2/3-view caches filled here with --prepare-only; the 4-view stereo is made there, before timing)
set -u
mkdir -p /tmp/cache_q /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache_q/
export REINGS_CACHE_DIR=/tmp/cache_q
R="bash scripts/lent_gpu.sh"
G="--dataset llff --root .gpu_llff/data/llff --scenes fern,flower --views 2,3,4 --methods reings,dngaussian --preset quick --no-lpips --device cuda"
t(){ local tag=$1 lim=$2; shift 2; local t0=$(date +%s%N); timeout $lim $R eval $G --out /tmp/g/$tag "$@" > /tmp/g/$tag.log 2>&1; echo "$tag rc=$? elapsed_ms $(( ($(date +%s%N) - t0) / 1000000 )) runs $(find /tmp/g/$tag -name metrics.json | wc -l)" | tee -a /tmp/g/summary.txt; pkill -9 -f multiprocessing.spawn; sleep 1; }
nvidia-smi -L > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt; lscpu | grep 'Model name' >> /tmp/g/machine.txt; $R devices >> /tmp/g/machine.txt 2>&1
# kernels compiled once for both devices before timing (as a user's second grid finds them)
timeout 100 $R run --preset quick --iterations 2 --device pocl --out /tmp/warm_pocl > /tmp/g/warm.txt 2>&1
timeout 60 $R run --preset quick --iterations 2 --device cuda --out /tmp/warm_cuda >> /tmp/g/warm.txt 2>&1
t0=$(date +%s); timeout 200 $R eval $G --out /tmp/prep --prepare-only > /tmp/g/prep.txt 2>&1; echo "prepare rc=$? $(( $(date +%s) - t0 )) s" | tee -a /tmp/g/summary.txt
t serial 150
t gpu1_pocl3 300 --cluster local:4
cd /tmp/g && tar czf $OUT/grids.tgz --exclude='*.png' --exclude='*.ply' --exclude=checkpoints --exclude=depths --exclude=renders .
