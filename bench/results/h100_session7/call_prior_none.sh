set -u
# issue 12: LLFF with --depth-prior none, full schedule, reings and dngaussian, seeds 0-2; renders kept for LPIPS
V=$1; LIM=${2:-540}
mkdir -p /tmp/cache_q /tmp/g; cp -r --update=none .gpudata/cache_q/* /tmp/cache_q/
export REINGS_CACHE_DIR=/tmp/cache_q
t0=$(date +%s)
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpudata/llff --scenes fern,flower --views $V \
  --methods reings,dngaussian --seeds 0,1,2 --preset paper --device cuda --no-lpips --depth-prior none \
  --out /tmp/g/none$V --cluster local:12 --runs-per-gpu 12 --gpu-only > /tmp/g/none$V.log 2>&1
echo "none$V rc=$? $(( $(date +%s) - t0 )) s runs $(find /tmp/g/none$V -name metrics.json | wc -l)" | tee -a /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
cd /tmp/g && tar czf $OUT/none$V.tgz --exclude='*.ply' --exclude=checkpoints --exclude=depths none$V none$V.log summary.txt
