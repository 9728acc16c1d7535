set -u
# session 40, call 3: the held-out scene trex (NeX format; session 38's full schedule, the default: 22.5522 / 22.4928 /
# 22.6417, mean 22.562) under the CPU preset chosen on fern / flower / room in call 2 (--preset fast, now reings
# 600/600/2400) and under its former 300/300/1200, 3 views, seeds 0-2, one run at a time.
# Predicted: the new preset within 0.3 dB of the full schedule's mean, above the former preset.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/runs; mkdir -p $T
one() { # seed tag options...
  s=$1; tag=$2; shift 2
  timeout 100 python3 -m reings.cli eval --dataset llff_nex --root $R/$CARRY/data/llff_nex --scenes trex --views 3 --seeds $s \
    --methods reings --preset fast --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_$s.txt 2>&1
}
for s in 0 1 2; do
  one $s fast
  one $s fast_300_300_1200 --iterations 300,300,1200
done
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/3views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["final_prune"], m["config"].get("iterations"))
PY
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
