set -u
# issue 15, checkpoints: on a lent H100, bench_checkpoint.py on cuda:0, then full-schedule fern runs
# (3 views, seed 0, --preset paper, no LPIPS), one at a time, one per argument NAME:"extra options".
# usage: bash bench/results/pocl_xeon_2core_session13_checkpoints/gpu_call.sh [bench] NAME:"opts" ...
C=.gpu_c1
mkdir -p /tmp/cache /tmp/g; cp -r $C/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache
[ -d /tmp/site/pyopencl ] || python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/machine.txt; nproc >> $OUT/machine.txt
df -h /tmp >> $OUT/machine.txt
for v in "$@"; do
  if [ "$v" = bench ]; then
    python3 bench/bench_checkpoint.py --device cuda:0 --dir /tmp --label h100-tmp --json $OUT/checkpoint_h100.jsonl 2>&1 | grep -v "^WARNING: Target"
    continue
  fi
  name=${v%%:*}; opts=${v#*:}
  t=$(date +%s.%N)
  timeout 240 python3 -m reings.cli eval --dataset llff --root $C/data/llff --scenes fern --views 3 --seeds 0 \
    --methods reings --preset paper --device cuda:0 --no-lpips --out /tmp/g/$name $opts 2>&1 | grep -v "^WARNING: Target"
  echo "$name: process $(echo "$(date +%s.%N) - $t" | bc) s"
  f=$(find /tmp/g/$name -name metrics.json)
  python3 - "$f" "$name" <<'PY'
import hashlib, json, os, sys
f, name = sys.argv[1:]
m = json.load(open(f))
fits = [s for s in m["stages"] if s.get("iterations")]
ply = hashlib.sha256(open(os.path.join(os.path.dirname(f), "gaussians.ply"), "rb").read()).hexdigest()[:16]
ph = {}
for s in fits:
    for k, v in s.get("phases", {}).items():
        ph[k] = ph.get(k, 0) + v
print(name, "psnr", m["mean"]["psnr"], "ply", ply, "method_s", round(m["seconds"]["method"], 2),
      "total_s", round(m["seconds"]["total"], 2), "probes_s", round(m["seconds"].get("probes", 0), 2),
      {s["stage"]: (round(s["seconds"], 2), round(s["wall_seconds"], 2), s.get("checkpoints")) for s in fits})
if ph:
    print(name, "phases sum", round(sum(ph.values()), 2), "of wall", round(sum(s["wall_seconds"] for s in fits), 2),
          {k: round(v, 2) for k, v in sorted(ph.items(), key=lambda kv: -kv[1])})
PY
  cp "$f" $OUT/$name.metrics.json
done
