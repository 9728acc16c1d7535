set -u
# session 38, call 3: the held-out LLFF-family scene trex (NeX-format) at 3 views, seeds 0-2, full schedule: the
# working tree's default (the reings fits' hard depth pass at 1/2 resolution with 'area' patches, the LLFF family's
# since this session) against --hard-depth-scale 1 (full resolution, the default until now).
# Predicted: within 0.1 dB of --hard-depth-scale 1 on the mean of the three seeds (fern/flower/room: -0.06/+0.15/+0.29).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/tx; mkdir -p $T
one() { # seed tag options...
  s=$1; tag=$2; shift 2
  timeout 200 python3 -m reings.cli eval --dataset llff_nex --root $R/$CARRY/data/llff_nex --scenes trex --views 3 --seeds $s \
    --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_$s.txt 2>&1
}
timeout 90 python3 -m reings.cli eval --dataset llff_nex --root $R/$CARRY/data/llff_nex --scenes trex --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for s in 0 1 2; do
  one $s default &
  one $s s1 --hard-depth-scale 1
  wait
done
python3 - $T > $OUT/trex.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/3views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], round(m["mean"]["psnr"], 4), round(m["mean"]["ssim"], 4),
          round(sum(s[k] for k in ("coarse", "fine", "final")), 1), m["gaussians"]["final_prune"],
          m["config"].get("hard_depth_scale") if "config" in m else None)
PY
cat $OUT/trex.txt; tail -n 2 $T/*_0.txt > $OUT/tails.txt
