set -u
# session 42, call 6: the screen-size prune relative to the image (--max-screen-fraction 1: at each densification
# step the Gaussians whose 3-sigma screen radius in a training view exceeded the view's larger side are pruned).
# Call 5 showed what broke flower's seed 2 under call 2's A (17.84 dB; test views 008 / 024 at 4.9 / 9.3 dB): one
# Gaussian 2.3 units in front of test camera 008 (the scene's nearest 1 % at ~23), opacity 1, near-white, its 3-sigma
# radius 1944 px there, 985-2399 px in the training views (whose images it enters only with its tail).
# Predicted: flower A seed 2 back to >= 20.5 dB (the floater pruned); the default's flower / fern / room runs within
# 0.15 dB of their digits (2,1,1: flower 21.3859 / 21.3336 / 21.2383, fern 22.2580, room 21.8192).
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
T=/tmp/runs6; mkdir -p $T
summary() {
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/*views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["views"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "stages", round(s["coarse"], 1), round(s["fine"], 1), round(s["final"], 1),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["coarse"], m["gaussians"]["fine"], m["gaussians"]["final_prune"], m["config"].get("fit_scale"),
          m["config"].get("view_warp_scale"), m["config"].get("fit_scale_share"), m["config"].get("max_screen_fraction"))
PY
}
one() { # dataset scene views seed preset tag options...
  ds=$1; sc=$2; v=$3; s=$4; pr=$5; tag=$6; shift 6
  [ $(( $(date +%s) - T0 )) -gt 320 ] && return
  timeout 60 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views $v --seeds $s \
    --methods reings --preset $pr --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_${v}_$s.txt 2>&1
}
one llff flower 3 2 paper shAsp --fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --max-screen-fraction 1; summary
for s in 0 1 2; do one llff flower 3 $s paper sp --max-screen-fraction 1; summary; done
one llff flower 3 0 paper shAsp --fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --max-screen-fraction 1; summary
one llff fern 3 0 paper sp --max-screen-fraction 1; summary
one llff_nex room 3 0 paper sp --max-screen-fraction 1; summary
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
