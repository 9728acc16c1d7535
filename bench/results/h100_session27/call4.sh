set -u
# session 27, call 4 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session27/call4.sh .gpu_s24
# The final code: (a) tests/test_sort.py and the photometric tests of tests/test_losses.py on the GPU (the fused SSIM kernels'
# bits against the four-pass ones on NVIDIA); (b) fern 3v seed 0 full schedule under host_wait, three configurations
# alternating: A = the defaults (onesweep, fused SSIM), B = REINGS_SORT_ONESWEEP=0 REINGS_SSIM_FUSED=0 (the session's
# start), C = REINGS_SSIM_FUSED=0 (onesweep alone); A B C A B C A, then B C while under 470 s.
CARRY=$1; R=$PWD; T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
REINGS_TEST_DEVICES=cuda timeout 120 python3 -m pytest -q tests/test_sort.py tests/test_losses.py -k "not oclgrind and (sort or onesweep or photometric or scan)" -p no:cacheprovider 2>&1 | tail -3 > $OUT/tests.txt; cat $OUT/tests.txt
run() {
  name=$1; shift
  env "$@" timeout 100 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  for f in $T/hw_*.txt; do echo "== $f"; cat $f; done > $OUT/fern.txt
  tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
}
A="REINGS_SORT_ONESWEEP=1"; B="REINGS_SORT_ONESWEEP=0 REINGS_SSIM_FUSED=0"; C="REINGS_SSIM_FUSED=0"
run A_1 $A; run B_1 $B; run C_1 $C; run A_2 $A; run B_2 $B; run C_2 $C; run A_3 $A
[ $(( $(date +%s) - T0 )) -lt 470 ] && run B_3 $B
[ $(( $(date +%s) - T0 )) -lt 470 ] && run C_3 $C
grep -E "training|launches" $OUT/fern.txt | grep -v other
