set -u
# session 42, call 5: call 4's flower runs at seeds 2 and 1 again (test views 008 / 024 at 4.9 / 9.3 dB in seed 2, 15.1 /
# 15.5 in seed 1; 000 / 016 / 032 at 24-26 in both), their folders brought back (the model, the test renders and depths)
# to see what covers views 008 and 024.
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/gpu.txt
T=/tmp/runs5; mkdir -p $T
summary() {
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/*views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["views"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "stages", round(s["coarse"], 1), round(s["fine"], 1), round(s["final"], 1),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["coarse"], m["gaussians"]["fine"], m["gaussians"]["final_prune"], m["config"].get("fit_scale"),
          m["config"].get("view_warp_scale"), m["config"].get("fit_scale_share"))
PY
}
one() { # dataset scene views seed preset tag options...
  ds=$1; sc=$2; v=$3; s=$4; pr=$5; tag=$6; shift 6
  [ $(( $(date +%s) - T0 )) -gt 545 ] && return
  timeout 60 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views $v --seeds $s \
    --methods reings --preset $pr --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_${v}_$s.txt 2>&1
}
for s in 2 1; do one llff flower 3 $s paper shA --fit-scale 2,2,1 --fit-scale-share 1,0.5,1; summary; done
cat $OUT/runs.txt
cd $T/shA/llff/reings/3views && tar czf $OUT/runs.tgz --exclude=checkpoints flower_seed2 flower_seed1
