set -u
# session 25, call 5 (nvidia-h100-x1). Run from the repository root: bash call5.sh .gpu_s24
# adam_step_multi stepping the SH groups' strided views flat (DeviceTrainer.adam_flat_views, the GPUs' new default):
# (a) scene C's step profiled per stage at SH 0 / 3, flat views off / on (no gsplat); (b) peer_step C, SH 0 / 3,
# against gsplat, 3 rounds, the new default; (c) one fern 3v run (the PSNR digits).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $T/machine.txt
cd .gpu_clean
for fv in 0 1 0 1; do
  REINGS_QUEUE_PROFILING=1 PYTHONPATH=/tmp/site:$PWD timeout 120 python3 -c "
import runpy, sys
import reings.backends.opencl.trainer as T
init = T.DeviceTrainer.__init__
def patched(self, *a, **k):
    init(self, *a, **k)
    self.adam_flat_views = bool($fv)
T.DeviceTrainer.__init__ = patched
sys.argv = ['peer_step.py', '--device', 'cuda', '--scenes', 'C', '--sh', '0,3', '--no-gsplat', '--ref-crop', '-1',
            '--json', '$T/prof_flat$fv.jsonl']
runpy.run_path('bench/peer_step.py', run_name='__main__')
" > /dev/null 2>&1
done
python3 - $T <<'PY' > $T/summary.txt
import json, sys, glob, os
for f in sorted(glob.glob(sys.argv[1] + "/prof_*.jsonl")):
    for l in open(f):
        d = json.loads(l)
        if d.get("kind") == "step":
            print(os.path.basename(f), "SH", d["sh"], "wall", round(d["ours_step_wall_ms"], 3), "adam",
                  round(d["ours_dev_adam_ms"], 4), "sum", round(d["ours_dev_sum_ms"], 4))
PY
cp $T/summary.txt $OUT/
PYTHONPATH=/tmp/site:$PWD timeout 200 python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --rounds 3 \
  --json $T/peer.jsonl > $T/peer.txt 2>&1
cp $T/peer.txt $OUT/
PYTHONPATH=/tmp/site:$PWD timeout 110 python3 bench/host_wait.py --out $T/new_1.json -- eval --dataset llff \
  --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 \
  --no-lpips --out $T/new_1 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/fern.txt
python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('new_1', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
  $T/new_1/llff/reings/3views/fern/metrics.json >> $T/fern.txt 2>&1
cp $T/fern.txt $OUT/
tar -czf $OUT/raw.tgz -C $T $(cd $T && ls *.jsonl *.json machine.txt)
cat $T/machine.txt $T/summary.txt $T/fern.txt; grep -A4 '^# ours' $T/peer.txt
