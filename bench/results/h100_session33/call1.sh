set -u
# session 33, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session33/call1.sh .gpu30 .old33
# NEW (this tree: isect_reduce's GPU schedule, RED_LANES work-items per rank staging records in local memory, the same
# bits) against OLD (6b40a1b, copied to $2). 1: the GPU tests of the rasterizer. 2: bench_rasterize on C and A, OLD and
# NEW (device times of fwd / bwd / reduce), and A/B experiments of the backward in one process (native exp, a probe
# without the per-Gaussian warp sums, BWD_BATCH 64, RED_LANES 32). 3: per-stage step profiles OLD / NEW. 4: fern full
# schedule NEW (PSNR must stay 22.330038). 5: the step against gsplat.
CARRY=$1; OLDT=$2; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 240 python3 -m pytest -q -x -p no:cacheprovider tests/test_rasterize.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
B="--device cuda --runs 30 --warmup 5 --no-count"
for sc in C A; do
  (cd $R/$OLDT && PYTHONPATH=/tmp/site:$R/$OLDT timeout 120 python3 bench/bench_rasterize.py $B --scene $sc > $OUT/rast_old_$sc.txt 2>&1)
  timeout 120 python3 bench/bench_rasterize.py $B --scene $sc > $OUT/rast_new_$sc.txt 2>&1
  for ab in RASTER_NATIVE_EXP RASTER_BWD_PROBE; do
    timeout 200 python3 bench/bench_rasterize.py $B --scene $sc --define $ab=0 --against $ab=1 > $OUT/ab_${ab}_$sc.txt 2>&1
  done
  timeout 200 python3 bench/bench_rasterize.py $B --scene $sc --define BWD_BATCH=32 --against BWD_BATCH=64 > $OUT/ab_BWD_BATCH_$sc.txt 2>&1
  timeout 200 python3 bench/bench_rasterize.py $B --scene $sc --define RED_LANES=16 --against RED_LANES=32 > $OUT/ab_RED_LANES_$sc.txt 2>&1
done
(cd $R/$OLDT && PYTHONPATH=/tmp/site:$R/$OLDT REINGS_QUEUE_PROFILING=1 timeout 150 python3 bench/peer_step.py --device cuda --scenes A,C --sh 0,3 --no-gsplat > $OUT/prof_old.txt 2>&1)
REINGS_QUEUE_PROFILING=1 timeout 150 python3 bench/peer_step.py --device cuda --scenes A,C --sh 0,3 --no-gsplat > $OUT/prof_new.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 150 python3 -m reings.cli $EV --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
/usr/bin/time -f "wall %e s" timeout 150 python3 -m reings.cli $EV --out $T/P1 > $T/P1.txt 2>&1
python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $T/P1/llff/reings/3views/fern/metrics.json > $OUT/fern.txt 2>&1
tail -1 $T/P1.txt >> $OUT/fern.txt
timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
grep -h "device ms" $OUT/prof_old.txt $OUT/prof_new.txt
for f in $OUT/rast_*.txt $OUT/ab_*.txt; do echo "== $f"; grep -iE "median|ratio|fwd |bwd |reduce" $f | tail -8; done
cat $OUT/fern.txt $OUT/peer_summary.txt $OUT/device.txt
