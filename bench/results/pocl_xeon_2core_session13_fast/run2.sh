cd /work/main; source .venv/bin/activate
export REINGS_CACHE_DIR=/tmp/cache_fast
for sc in flower; do
  /usr/bin/time -v reings eval --dataset llff --root .gpu_s13/data/llff --scenes $sc --views 3 --seeds 0 --methods reings --preset fast --iterations 300,300,1200 --soft-depth-shared --device pocl --no-lpips --out /tmp/fast_exp/x15_f1200_shared > /tmp/fast_exp/${sc}_f1200.log 2>&1
done
