set -u
# session 41, call 2: the held-out NeX trex with the coarse and fine fits at 1/2 resolution (--fit-scale 2,2,1), full
# schedule, 3 views, seeds 0-2, one run at a time, against the default (session 38's digits: 22.5522 / 22.4928 /
# 22.6417). Predicted: within 0.15 dB on the mean (call 1: fern -0.07, flower -0.11, room +0.50).
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
T=/tmp/runs; mkdir -p $T
summary() {
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/*views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["views"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "stages", round(s["coarse"], 1), round(s["fine"], 1), round(s["final"], 1),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["coarse"], m["gaussians"]["fine"], m["gaussians"]["final_prune"], m["config"].get("fit_scale"))
PY
}
one() { # dataset scene views seed preset tag options...
  ds=$1; sc=$2; v=$3; s=$4; pr=$5; tag=$6; shift 6
  [ $(( $(date +%s) - T0 )) -gt 545 ] && return
  timeout 120 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views $v --seeds $s \
    --methods reings --preset $pr --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_${v}_$s.txt 2>&1
}
for s in 0 1 2; do one llff_nex trex 3 $s paper s221 --fit-scale 2,2,1; done
summary
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
