set -u
# session 18, call 3 (nvidia-h100-x1, one H100 alone): the sort geometry (docs/perf_notes.md §10).
# (1) bench_sort_geometry.py sweep; (2) bench_host.py wall, three sort geometries alternating, twice, with a
# bit check of the final states; (3) device_time.py per geometry; (4) fern 3 views, seed 0, full schedule,
# the defaults, per geometry. CARRY = $1 (.gpu_s24: fern, SfM caches, fern's 3-view stereo cache).
# Geometries: S0 = the default (items 8, wg 256, 8 bits); S1 = REINGS_SORT_ITEMS=auto; S2 = auto + 11-bit digits.
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
geo() {  # S0|S1|S2 -> env assignments
  case $1 in S0) echo "";; S1) echo "REINGS_SORT_ITEMS=auto";; S2) echo "REINGS_SORT_ITEMS=auto REINGS_SORT_BITS=11";; esac
}
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/sort_geometry.txt $T/bench_host.txt $T/summary.txt 2>/dev/null; } > $OUT/timing.txt; cp $T/*.jsonl $OUT/ 2>/dev/null; }
timeout 200 python3 bench/bench_sort_geometry.py --device cuda:0 --repeats 50 --out $T/sort_geometry.jsonl 2>&1 | grep -v "^WARNING: Target" > $T/sort_geometry.txt
out
for rep in 1 2; do
  for g in S0 S1 S2; do
    env $(geo $g) timeout 60 python3 bench/bench_host.py --device cuda:0 --mode wall --iterations 401 --label $g-$rep \
      --json $T/bench_host.jsonl --save $T/state_$g.npz 2>&1 | grep -v "^WARNING: Target" >> $T/bench_host.txt
  done
done
python3 - >> $T/bench_host.txt 2>&1 <<'PY'
import numpy as np
a = np.load('/tmp/timing/state_S0.npz')
for g in ('S1', 'S2'):
    b = np.load(f'/tmp/timing/state_{g}.npz')
    print(g, 'vs S0: arrays', len(a.files), 'different', [k for k in a.files if not np.array_equal(a[k], b[k])])
PY
for g in S0 S1 S2; do
  echo "device_time $g" >> $T/bench_host.txt
  env $(geo $g) timeout 60 python3 bench/results/issue15_depth_order/device_time.py --device cuda:0 --pairs 1 2>&1 | grep -v "^WARNING: Target" | grep share >> $T/bench_host.txt
done
out
run() {  # NAME GEOMETRY
  name=$1; g=$2
  env $(geo $g) timeout 130 bash scripts/lent_gpu.sh eval --dataset llff --root $CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  out
}
run S0_1 S0
run S1_1 S1
run S2_1 S2
run S0_2 S0
rm -f $T/state_*.npz
out
cat $OUT/timing.txt
