set -u
# session 34, call 3. Run from the repository root: bash bench/results/h100_session34/call3.sh .gpu30
# Call 2's fern runs left no metrics (their logs stayed on the device): fern seeds 1 and 2 again, logs kept.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing3; mkdir -p $T
ls /tmp/timing2/ > $OUT/call2_leftovers.txt 2>&1; tail -n 5 /tmp/timing2/*.txt >> $OUT/call2_leftovers.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
for sd in 1 2; do
  timeout 150 python3 -m reings.cli $EV --seeds $sd --out $T/P$sd > $OUT/P$sd.txt 2>&1
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('seed', sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $T/P$sd/llff/reings/3views/fern/metrics.json $sd | tee -a $OUT/fern.txt
done
tail -n 3 $OUT/P*.txt
