set -u
# session 34, call 2. Run from the repository root: bash bench/results/h100_session34/call2.sh .gpu30
# 1: the GPU tests of the rasterizer and the projection again (call 1 stopped at a test artifact, now a skip).
# 2: fern full schedule seeds 1 and 2 (defaults), timing on this host. 3: the step against gsplat again, 3 rounds.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing2; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -p no:cacheprovider tests/test_rasterize.py tests/test_project.py -k "not oclgrind" > $OUT/tests.txt 2>&1; tail -3 $OUT/tests.txt
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
timeout 60 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for sd in 1 2; do
  timeout 80 python3 -m reings.cli $EV --seeds $sd --out $T/P$sd > $T/P$sd.txt 2>&1
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('seed', sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $T/P$sd/llff/reings/3views/fern/metrics.json $sd | tee -a $OUT/fern.txt
done
timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
cat $OUT/peer_summary.txt $OUT/device.txt
