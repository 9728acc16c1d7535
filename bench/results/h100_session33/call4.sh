set -u
# session 33, call 4 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session33/call4.sh .gpu33
# Is call 3's flower seed 2 at BWD_PIX 2 (19.61 against 21.04 at BWD_PIX 1) chance or systematic? Seed 2 at BWD_PIX 4
# (a third rounding of the same sums), and seeds 3 and 4 at BWD_PIX 1 and 2, flower full schedule.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing4; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 --version; } > $OUT/device.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes flower --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), round(m['mean']['ssim'],5), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1 $2; }
for p in 1 2 4; do REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm$p > $T/warm$p.txt 2>&1; done
for job in "4 2" "1 3" "2 3" "1 4" "2 4"; do
  set -- $job; p=$1; sd=$2
  REINGS_BWD_PIX=$p timeout 150 python3 -m reings.cli $EV --seeds $sd --out $T/P${p}s$sd > $T/P${p}s$sd.txt 2>&1
  f=$(ls $T/P${p}s$sd/llff/reings/3views/*/metrics.json | head -1); summ $f flower_pix${p}_seed$sd >> $OUT/flower.txt 2>&1
done
cat $OUT/flower.txt $OUT/device.txt
