set -u
# session 33, call 2 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session33/call2.sh .gpu30
# This tree: isect_reduce's GPU schedule as one work-item per rank with the group's contiguous block of records
# staged in local memory (the same bits), and rasterize_bwd's BWD_PIX pixels per work-item (default 1: the same
# bits; REINGS_BWD_PIX=2|4 the experiment). 1: the GPU tests of the rasterizer. 2: bench_rasterize on C and A, and
# BWD_PIX A/Bs in one process. 3: fern full schedule seeds 0-2 at BWD_PIX 1 and 2, alternating. 4: the step against
# gsplat at BWD_PIX 2.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing2; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -x -p no:cacheprovider tests/test_rasterize.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
B="--device cuda --runs 30 --warmup 5 --no-count"
for sc in C A; do
  timeout 120 python3 bench/bench_rasterize.py $B --scene $sc > $OUT/rast_new_$sc.txt 2>&1
  for p in 2 4; do
    timeout 200 python3 bench/bench_rasterize.py $B --scene $sc --define BWD_PIX=1 --against BWD_PIX=$p > $OUT/ab_pix${p}_$sc.txt 2>&1
  done
done
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), round(m['mean']['ssim'],5), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1 $2; }
for p in 1 2; do REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm$p > $T/warm$p.txt 2>&1; done
for sd in 0 1 2; do
  for p in 1 2; do
    REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds $sd --out $T/P${p}s$sd > $T/P${p}s$sd.txt 2>&1
    f=$(ls $T/P${p}s$sd/llff/reings/3views/*/metrics.json | head -1); summ $f pix${p}_seed$sd >> $OUT/fern.txt 2>&1
  done
done
REINGS_BWD_PIX=2 timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
cd $OUT && tar czf raw.tgz rast_*.txt ab_*.txt tests.txt peer.txt peer.jsonl && rm -f rast_*.txt ab_*.txt peer.txt peer.jsonl; cd $R
tar xzf $OUT/raw.tgz -O --wildcards 'rast_*' | grep -E "^  (fwd|bwd|reduce) "
tar xzf $OUT/raw.tgz -O --wildcards 'ab_*' | grep '"bwd"\|"fwd"' | python3 -c "
import json,sys
for l in sys.stdin:
    d=json.loads(l); print(d['scene'], d['stage'], d['b_defines'], d['a_median_ms'], d['b_median_ms'], d['ratio_median'], d['ratio_q25_q75'])"
cat $OUT/fern.txt $OUT/peer_summary.txt $OUT/device.txt
