set -u
# session 31, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session31/call1.sh .gpu30
# The host (CPU model), fern at 3 views seed 0 full schedule three times as a user runs it (plain `reings eval`, no
# wrapper), once under host_wait (launches, enqueue µs), and once under the kernel census (device ms per step per kernel).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing1; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)|MHz"; python3 --version; } > $OUT/device.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1/llff/reings/3views/fern/metrics.json $2; }
# warm the kernel cache once (a short run), so no plain run builds
timeout 120 python3 -m reings.cli $EV --iterations 30,30,30 --out $T/warm > $T/warm.txt 2>&1
for k in P1 P2 P3; do
  /usr/bin/time -f "$k wall %e s" timeout 100 python3 -m reings.cli $EV --out $T/$k > $T/$k.txt 2>&1
  summ $T/$k $k >> $OUT/fern.txt 2>&1; tail -1 $T/$k.txt >> $OUT/fern.txt
done
timeout 100 python3 bench/host_wait.py --out $T/hw.json -- $EV --out $T/HW 2>&1 | grep -v "^WARNING: Target" | tail -6 >> $OUT/fern.txt
summ $T/HW HW >> $OUT/fern.txt 2>&1
timeout 200 python3 bench/kernel_census.py --out $T/census.json -- $EV --out $T/CE > $T/census.txt 2>&1
summ $T/CE CENSUS >> $OUT/fern.txt 2>&1
tail -40 $T/census.txt > $OUT/census_console.txt
tar -czf $OUT/raw.tgz -C $T hw.json census.json
cat $OUT/fern.txt; cat $OUT/device.txt
