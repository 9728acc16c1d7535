set -u
# session 40, call 1: the view_warp term at every 2nd iteration, its weight x2 (--view-warp-every 2), against the
# default (every iteration; session 38's digits, the same code path on NVIDIA: fern 22.3598 / 22.2314 / 22.1712,
# flower 21.1994 / 21.1421 / 21.5354, room 21.7432 / 22.0574 / 21.3225), full schedule, 3 views, seeds 0-2, one run
# at a time; then the CPU preset (--preset fast) on fern and flower, seeds 0-2, with both settings.
# Predicted: within 0.1 dB of the default on the mean of the three seeds per scene; training ~10 % shorter.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
T=/tmp/runs; mkdir -p $T
summary() {
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/3views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["final_prune"], m["config"].get("view_warp_every"))
PY
}
one() { # dataset scene seed preset tag options...
  ds=$1; sc=$2; s=$3; pr=$4; tag=$5; shift 5
  timeout 150 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views 3 --seeds $s \
    --methods reings --preset $pr --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_$s.txt 2>&1
}
for s in 0 1 2; do
  for sc in fern flower; do one llff $sc $s paper every2 --view-warp-every 2; done
  one llff_nex room $s paper every2 --view-warp-every 2
done
summary
for s in 0 1 2; do
  for sc in fern flower; do
    one llff $sc $s fast fast1
    one llff $sc $s fast fast2 --view-warp-every 2
  done
done
summary
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
