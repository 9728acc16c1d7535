set -u
# session 25, call 3 (nvidia-h100-x1). Run from the repository root: bash call3.sh .gpu_s24
# (a) the changed kernels' tests on NVIDIA (project_bwd's accumulate mode, project_fwd's records, bin_count on the GPU
# schedule, the scan, the held-gradient backwards, the regularizer's counters, the layouts); (b) fern 3v seed 0 full
# schedule under host_wait, NEW (.gpu_clean = HEAD) / OLD (.gpu_old = eee68ce) alternating, two pairs.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $T/machine.txt
(cd .gpu_clean && REINGS_TEST_DEVICES=cuda PYTHONPATH=/tmp/site:$PWD timeout 330 python3 -m pytest -q -p no:cacheprovider \
  tests/test_project.py tests/test_bin.py tests/test_view_warp_fit.py tests/test_adam_kernel.py tests/test_layouts.py \
  tests/test_background.py -k "not oclgrind" 2>&1 | tail -12 > $T/tests.txt)
(cd .gpu_clean && REINGS_TEST_DEVICES=cuda PYTHONPATH=/tmp/site:$PWD timeout 90 python3 -m pytest -q -p no:cacheprovider \
  tests/test_sort.py -k "scan and not oclgrind" 2>&1 | tail -4 >> $T/tests.txt)
cp $T/tests.txt $OUT/
run() {
  name=$1; tree=$2
  S=$R/$tree
  (cd $S && PYTHONPATH=/tmp/site:$S timeout 110 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  cat $T/hw_*.txt > $OUT/fern.txt
}
cp $R/.gpu_clean/bench/host_wait.py $R/.gpu_old/bench/host_wait.py
run new_1 .gpu_clean; run old_1 .gpu_old; run new_2 .gpu_clean; run old_2 .gpu_old
tar -czf $OUT/raw.tgz -C $T $(cd $T && ls *.json machine.txt)
cat $T/machine.txt $T/tests.txt $OUT/fern.txt
