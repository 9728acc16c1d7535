set -u
# session 30, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session30/call1.sh .gpu30
# The device's OpenCL extensions (is cl_khr_command_buffer there?); the step against gsplat 1.5.3 on A, B, C at SH 0
# and 3; fern at 3 views, seed 0, full schedule, three runs alone; `reings run --preset quick` on the procedural scene
# twice on the GPU (the first renders the scene into an empty cache, the second reads it).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
python3 - >> $OUT/device.txt 2>&1 <<'PY'
import pyopencl as cl
for p in cl.get_platforms():
    for d in p.get_devices():
        ext = d.extensions.split()
        print(p.name, "|", d.name, "|", d.version, "|", d.driver_version)
        print("command buffer extensions:", [e for e in ext if "command_buffer" in e] or "none")
        print("all:", " ".join(sorted(ext)))
PY
timeout 300 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
run() {
  name=$1
  timeout 100 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2), 'on clock', [st.get('kernel_builds_on_clock') for st in m['stages'] if 'kernel_builds_on_clock' in st])" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
run S1; run S2; run S3
# the procedural scene through the run's disk cache: an empty cache folder, then the same command again
for k in 1 2; do
  /usr/bin/time -f "wall %e s" env REINGS_CACHE_DIR=/tmp/pcache python3 -m reings.cli run --device cuda:0 --preset quick \
    --out $T/proc$k --overwrite --no-lpips > $T/proc$k.txt 2>&1
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('proc$k', round(m['mean']['psnr'],6), {k: round(v, 2) for k, v in s.items()})" $T/proc$k/metrics.json >> $OUT/proc.txt 2>&1
  tail -1 $T/proc$k.txt >> $OUT/proc.txt
done
python3 - > $OUT/peer_summary.txt <<'PY'
import json, os
for l in open(os.environ['OUT'] + '/peer.jsonl'):
    d = json.loads(l)
    if d.get('kind') == 'step':
        print(d['scene'], d['sh'], 'ours', round(d['ours_step_wall_ms'], 3), 'gsplat', round(d['gsplat_step_wall_ms'], 3),
              'ratio', round(d['ratio_wall'], 3), 'rounds', [round(x, 3) for x in d['ratio_wall_rounds']])
PY
cat $OUT/peer_summary.txt; grep -E "training" $OUT/fern.txt; cat $OUT/proc.txt; head -3 $OUT/device.txt
