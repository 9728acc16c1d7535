set -u
# session 38, call 4: the new default (the LLFF family's hard depth pass at 1/2 resolution with 'area' patches) at
# 2 views, where the geometry is weakest: fern and flower, seeds 0-2, the default against --hard-depth-scale 1, paired
# runs two at a time. Predicted: within 0.2 dB of the full pass on each scene's mean (3 views: -0.06 / +0.15).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/v2; mkdir -p $T
one() { # scene seed tag options...
  sc=$1; s=$2; tag=$3; shift 3
  timeout 150 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes $sc --views 2 --seeds $s \
    --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$tag "$@" > $T/${tag}_${sc}_$s.txt 2>&1
  d=$sc; [ $s != 0 ] && d=${sc}_seed$s
  f=$T/$tag/llff/reings/2views/$d/metrics.json; [ -f $f ] || f=
  [ -n "$f" ] && python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], m['scene'], m['seed'], round(m['mean']['psnr'],4), round(m['mean']['ssim'],4), round(sum(s[k] for k in ('coarse','fine','final')),1), m['gaussians']['final_prune'], m['config'].get('hard_depth_scale'))" $f $tag >> $OUT/views2.txt
}
for s in 0 1 2; do
  for sc in fern flower; do
    one $sc $s default &
    one $sc $s s1 --hard-depth-scale 1
    wait
  done
done
cat $OUT/views2.txt
