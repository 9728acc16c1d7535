set -u
# session 38, call 1: accuracy of the pixel stop at T_MIN 1e-3 against 1e-4 (the full schedule, seeds 0-2,
# fern / flower (official LLFF) / room (NeX-format), paired; T_MIN through REINGS_CL_BUILD_OPTIONS=-DT_MIN=1e-3f,
# kernels/common.h's #ifndef). Predicted: mean PSNR within +-0.1 dB per scene.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/tmin; mkdir -p $T
nvidia-smi --query-gpu=name --format=csv,noheader > $OUT/gpu.txt; lscpu | grep "Model name" >> $OUT/gpu.txt
one() { # dataset root scene seed tag options
  timeout 280 env REINGS_CL_BUILD_OPTIONS="$6" python3 -m reings.cli eval --dataset $1 --root $R/$CARRY/data/$2 --scenes $3 \
    --views 3 --seeds $4 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$5 > $T/$5_$3_$4.txt 2>&1
}
timeout 90 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for s in 0 1 2; do
  for tag in base tmin3; do
    o=""; [ $tag = tmin3 ] && o="-DT_MIN=1e-3f"
    one llff llff fern $s $tag "$o" & one llff llff flower $s $tag "$o" & one llff_nex llff_nex room $s $tag "$o" &
  done
  wait
done
python3 - $T > $OUT/tmin.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/3views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], round(m["mean"]["psnr"], 4), round(m["mean"]["ssim"], 4),
          round(sum(s[k] for k in ("coarse", "fine", "final")), 1), m["gaussians"]["final_prune"])
PY
cat $OUT/tmin.txt
tar czf $OUT/logs.tgz -C $T . --exclude='*.ply' --exclude='*.npz' --exclude='*.png' 2>/dev/null; ls -la $OUT
