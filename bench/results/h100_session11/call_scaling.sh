set -u
# issue 17 (what the lent 2-GPU kind allows): the same 12-run quick grid (fern at 2/3/4 views, reings and
# dngaussian, seeds 0-1) through `reings eval --cluster` with 6 runs sharing each GPU, on 1 GPU
# (CUDA_VISIBLE_DEVICES=0) and on both; kernels compiled and caches filled before timing.
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_c4/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
R="bash scripts/lent_gpu.sh"
G="--dataset llff --root .gpu_c4/data/llff --scenes fern --views 2,3,4 --methods reings,dngaussian --seeds 0,1 --preset quick --no-lpips --device cuda --gpu-only"
nvidia-smi -L > $OUT/summary.txt; nproc >> $OUT/summary.txt
CUDA_VISIBLE_DEVICES=0 $R devices 2>&1 | grep -ci nvidia | sed 's/^/nvidia devices seen with CUDA_VISIBLE_DEVICES=0: /' >> $OUT/summary.txt
timeout 40 $R run --preset quick --iterations 2 --device cuda --out /tmp/warm > /dev/null 2>&1
t(){ local tag=$1 lim=$2; shift 2; local t0=$(date +%s%N); timeout $lim "$@" --out /tmp/g/$tag > /tmp/g/$tag.log 2>&1; echo "$tag rc=$? elapsed_ms $(( ($(date +%s%N) - t0) / 1000000 )) runs $(find /tmp/g/$tag -name metrics.json | wc -l)" >> $OUT/summary.txt; pkill -9 -f multiprocessing.spawn; sleep 1; }
t gpu1x6 100 env CUDA_VISIBLE_DEVICES=0 $R eval $G --cluster local:6 --runs-per-gpu 6
t gpu2x6 100 $R eval $G --cluster local:12 --runs-per-gpu 6
for d in gpu1x6 gpu2x6; do for f in $(find /tmp/g/$d -name metrics.json | sort); do python3 -c "import json; m=json.load(open('$f')); print('$d', m['method'], m['views'], m['seed'], round(m['mean']['psnr'],4), round(m['seconds']['total'],1))"; done; done >> $OUT/summary.txt
cd /tmp/g && tar czf $OUT/scaling_logs.tgz *.log
