# OLD (HEAD: adam_step_multi on CPUs) vs NEW (working tree: one Adam launch per group on CPUs), CPU preset fern seed 0
source /work/main/.venv/bin/activate
export REINGS_CACHE_DIR=/work/main/.gpu30/cache
for tree in NEW OLD; do
  src=/work/main; [ $tree = OLD ] && src=/tmp/old33
  (cd $src && PYTHONPATH=$src /usr/bin/time -f "$tree wall %e s" python -m reings.cli eval --dataset llff --root /work/shared/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset fast --device pocl --no-lpips --out /tmp/s33/cpu_$tree > /tmp/s33/cpu_$tree.log 2>&1)
  python -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total',0),2))" /tmp/s33/cpu_$tree/llff/reings/3views/fern/metrics.json $tree >> /tmp/s33/cpu_ab.txt
done
