set -u
# issue 12, session 8, GPU call 1: the depth loss weighted by the stereo prior's confidence
# (--depth-confidence A), LLFF fern+flower, full schedule, seeds 0-2, reings with the other defaults.
#   A=1   at 2 and 3 views (12 runs), A=0.5 at 2 views (6 runs), and the default (A=0) fern 2v seed 0
#   as a reproduction check of docs/results.md §10 (18.96 dB on an H100). Renders kept for LPIPS.
LIM=${1:-540}
mkdir -p /tmp/cache /tmp/g; cp -r .gpu_llff/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
E="bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --scenes fern,flower --methods reings
   --seeds 0,1,2 --preset paper --device cuda --no-lpips --gpu-only"
t0=$(date +%s)
timeout $LIM $E --views 2,3 --depth-confidence 1 --out /tmp/g/conf1 --cluster local:12 --runs-per-gpu 12 > /tmp/g/conf1.log 2>&1 &
timeout $LIM $E --views 2 --depth-confidence 0.5 --out /tmp/g/conf05 --cluster local:6 --runs-per-gpu 6 > /tmp/g/conf05.log 2>&1 &
timeout $LIM bash scripts/lent_gpu.sh eval --dataset llff --root .gpu_llff/data/llff --scenes fern --views 2 --methods reings \
   --seeds 0 --preset paper --device cuda --no-lpips --out /tmp/g/default > /tmp/g/default.log 2>&1 &
wait
for g in conf1 conf05 default; do echo "$g $(( $(date +%s) - t0 )) s runs $(find /tmp/g/$g -name metrics.json | wc -l)"; done | tee /tmp/g/summary.txt
pkill -9 -f multiprocessing.spawn
printf "default\nconf1\nconf05\n" > /tmp/g/pack_order.txt
python3 scripts/pack_out.py /tmp/g $OUT --max-files 8
cat /tmp/g/*/results.md 2>/dev/null | head -60
