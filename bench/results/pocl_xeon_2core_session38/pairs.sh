# session 38: alternating shortened runs (the coarse fit's first 1200 iterations, 1 each of the others), the new
# default against --hard-depth-scale 1, A B B A, fern 3 views seed 0, 2 Xeon cores
source /work/main/.venv/bin/activate
cd /work/main
for t in full half half full; do
  o=""; [ $t = full ] && o="--hard-depth-scale 1"
  REINGS_CACHE_DIR=/work/main/.gpu30/cache reings eval --dataset llff --root /work/main/.gpu30/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device pocl --no-lpips --iterations 1200,1,1 $o --out /tmp/s38/pair_$t_$RANDOM > /tmp/s38/pair_log.txt 2>&1
  echo "$t $(grep 'coarse:' /tmp/s38/pair_log.txt)"
done
