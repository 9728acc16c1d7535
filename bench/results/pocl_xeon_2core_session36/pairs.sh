#!/bin/bash
# alternating shortened runs: old (5013dc6), new (HEAD worktree), new, old
source /work/main/.venv/bin/activate
for t in old new new old; do
  d=/tmp/wt36; [ $t = old ] && d=/tmp/wt36old
  o=/tmp/s36/pair_${t}_$RANDOM
  (cd $d && PYTHONPATH=$d REINGS_CACHE_DIR=/work/main/.gpu30/cache python -m reings.cli eval --dataset llff --root /work/main/.gpu30/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --iterations 600,300,300 --device pocl --no-lpips --out $o > $o.log 2>&1)
  f=$(ls $o/llff/reings/3views/fern/metrics.json)
  python -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], repr(m['mean']['psnr']), 'training', round(sum(s[k] for k in ('coarse','fine','final')),1), [round(s[k],1) for k in ('coarse','fine','final')])" $f $t
done
