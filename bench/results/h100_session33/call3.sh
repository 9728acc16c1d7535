set -u
# session 33, call 3 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session33/call3.sh .gpu33
# This tree: isect_reduce's GPU schedule back to call 1's 16 work-items per rank (call 2's work-item per rank over
# the group's staged block was slower), rasterize_bwd's BWD_PIX (default 1). 1: the rasterizer's GPU tests.
# 2: bench_rasterize on C and A. 3: flower full schedule seeds 0-2 at BWD_PIX 1 and 2, alternating (the held-out
# check of BWD_PIX 2's re-drawn rounding; fern's were in call 2).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing3; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q -x -p no:cacheprovider tests/test_rasterize.py -k "not oclgrind and (reduce or bwd or deterministic)" > $OUT/tests.txt 2>&1; tail -1 $OUT/tests.txt
B="--device cuda --runs 30 --warmup 5 --no-count"
for sc in C A; do timeout 120 python3 bench/bench_rasterize.py $B --scene $sc > $OUT/rast_new_$sc.txt 2>&1; grep -E "^  (fwd|bwd|reduce) " $OUT/rast_new_$sc.txt; done
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes flower --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), round(m['mean']['ssim'],5), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1 $2; }
for p in 1 2; do REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm$p > $T/warm$p.txt 2>&1; done
for sd in 0 1 2; do
  for p in 1 2; do
    REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds $sd --out $T/P${p}s$sd > $T/P${p}s$sd.txt 2>&1
    f=$(ls $T/P${p}s$sd/llff/reings/3views/*/metrics.json | head -1); summ $f flower_pix${p}_seed$sd >> $OUT/flower.txt 2>&1
  done
done
cat $OUT/flower.txt $OUT/device.txt
