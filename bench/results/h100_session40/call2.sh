set -u
# session 40, call 2: the CPU preset (--preset fast: reings 300/300/1200, SH 0, the stereo seeds, the shared soft
# depth term) at 1.5x and 2x its iterations (--iterations 450,450,1800 / 600,600,2400), fern and flower (issue 15's
# scenes) and room (NeX, held out), 3 views, seeds 0-2, one run at a time; and the preset as it is on room.
# Against the full schedule's means (session 38 / call 1: fern 22.254, flower 21.292, room 21.708) and the preset as it
# is (call 1: fern 21.896, flower 20.850). Predicted: +0.1 to +0.3 dB per scene at 1.5x, a little more at 2x.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/runs; mkdir -p $T
summary() {
python3 - $T > $OUT/runs.txt <<'PY'
import json, sys, glob
for f in sorted(glob.glob(sys.argv[1] + "/*/*/reings/3views/*/metrics.json")):
    m = json.load(open(f)); s = m["seconds"]
    print(f.split("/")[3], m["scene"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
          "training", round(sum(s[k] for k in ("coarse", "fine", "final")), 1), "total", round(s["total"], 1),
          m["gaussians"]["final_prune"], m["config"].get("iterations"))
PY
}
one() { # dataset scene seed tag options...
  ds=$1; sc=$2; s=$3; tag=$4; shift 4
  timeout 100 python3 -m reings.cli eval --dataset $ds --root $R/$CARRY/data/$ds --scenes $sc --views 3 --seeds $s \
    --methods reings --preset fast --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_$s.txt 2>&1
}
for s in 0 1 2; do
  for it in 450,450,1800 600,600,2400; do
    tag=fast_${it//,/_}
    one llff fern $s $tag --iterations $it
    one llff flower $s $tag --iterations $it
    one llff_nex room $s $tag --iterations $it
  done
  one llff_nex room $s fast1
  summary
done
cat $OUT/runs.txt; tail -n 2 $T/*.txt > $OUT/tails.txt
