set -u
# session 31, call 4 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session31/call4.sh .gpu30 .old31 .mid31
# Three trees alternating on one host, fern at 3 views seed 0 full schedule, plain `reings eval`: OLD (03b1ab8, session
# 30), MID (e44752a: call 2's NEW), NEW (this tree: the depth loss in 3 launches on GPUs); then the GPU tests of the
# depth loss (fused against separate kernels on NVIDIA) and of the device engine.
CARRY=$1; OLDT=$2; MIDT=$3; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing4; mkdir -p $T
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; } > $OUT/device.txt 2>&1
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips"
summ() { python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $1/llff/reings/3views/fern/metrics.json $2; }
src_of() { case $1 in OLD) echo $R/$OLDT;; MID) echo $R/$MIDT;; *) echo $R;; esac; }
for tree in OLD MID NEW; do  # warm each tree's kernel cache (a short run)
  src=$(src_of $tree)
  (cd $src && PYTHONPATH=/tmp/site:$src timeout 150 python3 -m reings.cli $EV --iterations 30,30,30 --out $T/warm$tree > $T/warm$tree.txt 2>&1)
done
for k in 1 2 3; do
  for tree in OLD MID NEW; do
    src=$(src_of $tree)
    (cd $src && PYTHONPATH=/tmp/site:$src /usr/bin/time -f "$tree$k wall %e s" timeout 100 python3 -m reings.cli $EV --out $T/$tree$k > $T/$tree$k.txt 2>&1)
    summ $T/$tree$k $tree$k >> $OUT/fern.txt 2>&1; tail -1 $T/$tree$k.txt >> $OUT/fern.txt
  done
done
export PYTHONPATH=/tmp/site:$R
REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q -p no:cacheprovider tests/test_depth_loss_kernel.py tests/test_device_fit.py -k "not oclgrind" > $OUT/tests.txt 2>&1
tail -3 $OUT/tests.txt
cat $OUT/fern.txt $OUT/device.txt
