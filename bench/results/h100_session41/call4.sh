set -u
# session 41, call 4: the coarse fit at 1/2 resolution (--fit-scale 2,1,1): (a) flower and room seed 2 (call 1 ran seeds
# 0-1), (b) 2 views, fern and flower, seeds 0-2 (default, session 38's digits: fern 21.3326 / 21.0397 / 21.3330, flower
# 20.1362 / 20.1385 / 20.1711), (c) the CPU preset (--preset fast, 600/600/2400) on fern, flower, room, seeds 0-2 (default,
# session 40's call 4: fern 22.5848 / 22.5507 / 22.4928, flower 21.0180 / 21.0774 / 21.2601, room 21.7747 / 21.6460 /
# 21.8711); then, as time allows, (d) the coarse fit at 1/4 (--fit-scale 4,1,1), seed 0 of fern, flower, room.
# Predicted: (a)-(c) within 0.15 dB of the default on each mean (call 1: fern +0.00, flower +0.19, room -0.09 on two
# seeds; call 3: trex -0.12).
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
T=/tmp/runs4; mkdir -p $T
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
  [ $(( $(date +%s) - T0 )) -gt 550 ] && return
  timeout 120 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views $v --seeds $s \
    --methods reings --preset $pr --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_${v}_$s.txt 2>&1
}
one llff flower 3 2 paper s211 --fit-scale 2,1,1
one llff_nex room 3 2 paper s211 --fit-scale 2,1,1
for s in 0 1 2; do for sc in fern flower; do one llff $sc 2 $s paper s211 --fit-scale 2,1,1; done; done
summary
for s in 0 1 2; do for sc in fern flower; do one llff $sc 3 $s fast fast211 --fit-scale 2,1,1; done
  one llff_nex room 3 $s fast fast211 --fit-scale 2,1,1; done
summary
for sc in fern flower; do one llff $sc 3 0 paper s411 --fit-scale 4,1,1; done
one llff_nex room 3 0 paper s411 --fit-scale 4,1,1
summary
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
