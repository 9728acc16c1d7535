set -u
# session 31, call 2 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session31/call2.sh .gpu30 .old31
# OLD (03b1ab8, session 30's code, copied to $2) against NEW (this tree: the host diet and project_bwd's densification
# statistics), fern at 3 views seed 0 full schedule, plain `reings eval`, alternating OLD, NEW three times on one host;
# the step against gsplat; the GPU tests of the changed code.
CARRY=$1; OLDT=$2; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing2; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; } > $OUT/device.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1/llff/reings/3views/fern/metrics.json $2; }
for tree in OLD NEW; do  # warm each tree's kernel cache (a short run)
  src=$R; [ $tree = OLD ] && src=$R/$OLDT
  (cd $src && PYTHONPATH=/tmp/site:$src timeout 150 python3 -m reings.cli $EV --iterations 30,30,30 --out $T/warm$tree > $T/warm$tree.txt 2>&1)
done
for k in 1 2 3; do
  for tree in OLD NEW; do
    src=$R; [ $tree = OLD ] && src=$R/$OLDT
    (cd $src && PYTHONPATH=/tmp/site:$src /usr/bin/time -f "$tree$k wall %e s" timeout 100 python3 -m reings.cli $EV --out $T/$tree$k > $T/$tree$k.txt 2>&1)
    summ $T/$tree$k $tree$k >> $OUT/fern.txt 2>&1; tail -1 $T/$tree$k.txt >> $OUT/fern.txt
  done
done
export PYTHONPATH=/tmp/site:$R
timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -x -p no:cacheprovider tests/test_device_fit.py tests/test_adam_kernel.py tests/test_project.py tests/test_kernel_builds.py -k "not oclgrind" > $OUT/tests.txt 2>&1
tail -3 $OUT/tests.txt
cat $OUT/fern.txt $OUT/peer_summary.txt $OUT/device.txt
