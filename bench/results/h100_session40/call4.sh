set -u
# session 40, call 4: the CPU preset at 2 views (the sparse end), fern and flower, seeds 0-2, one run at a time:
# --preset fast (now reings 600/600/2400, chosen at 3 views in calls 2-3) against its former 300/300/1200.
# The full schedule's default at 2 views (session 38, call 4): fern 21.3326 / 21.0397 / 21.3330, flower 20.1362 /
# 20.1385 / 20.1711. Predicted: the new preset at or above the former one on both scenes' means.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/runs; mkdir -p $T
one() { # scene seed tag options...
  sc=$1; s=$2; tag=$3; shift 3
  timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes $sc --views 2 --seeds $s \
    --methods reings --preset fast --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_$s.txt 2>&1
}
for s in 0 1 2; do
  for sc in fern flower; do
    one $sc $s fast
    one $sc $s fast_300_300_1200 --iterations 300,300,1200
  done
done
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/2views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["final_prune"], m["config"].get("iterations"))
PY
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
