set -u
# session 25, call 2 (nvidia-h100-x1). Run from the repository root: bash call2.sh .gpu_s24
# (a) launch_cost --buffer-sweep (the enqueue's cost per buffer argument); (b) bench_host's every-pass step,
# wall and stubbed, OLD (.gpu_old = eee68ce, code cbab11e) / NEW (.gpu_clean = HEAD) alternating, four pairs;
# (c) fern 3v seed 0 full schedule under host_wait, NEW / OLD alternating, two pairs; (d) peer_step C, 3 rounds.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $T/machine.txt
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD timeout 60 python3 bench/launch_cost.py --device cuda:0 --launches 2000 --repeats 3 \
  --buffer-sweep 0,1,2,4,8,16,32,64 --json $T/launch.jsonl > $T/launch.txt 2>&1)
for i in 1 2 3 4; do
  for t in .gpu_old .gpu_clean; do
    (cd $t && PYTHONPATH=/tmp/site:$PWD timeout 60 python3 bench/bench_host.py --device cuda:0 --mode wall --iterations 1000 \
      --log-every 100 --label "$t wall $i" --json $T/bench_host.jsonl 2>&1 | grep -v "^WARNING" | tail -1 | sed "s|^|$t $i |" >> $T/bench_host.txt)
  done
done
for t in .gpu_old .gpu_clean; do
  (cd $t && PYTHONPATH=/tmp/site:$PWD timeout 60 python3 bench/bench_host.py --device cuda:0 --mode stubbed --iterations 400 \
    --log-every 100 --label "$t stubbed" --json $T/bench_host.jsonl 2>&1 | grep -v "^WARNING" | tail -1 | sed "s|^|$t |" >> $T/bench_host.txt)
done
cp $T/launch.txt $T/bench_host.txt $OUT/
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
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD timeout 150 python3 bench/peer_step.py --device cuda --scenes C --sh 0,3 --rounds 3 --json $T/peer.jsonl > $T/peer.txt 2>&1)
cp $T/peer.txt $OUT/ 2>/dev/null
tar -czf $OUT/raw.tgz -C $T $(cd $T && ls *.json *.jsonl machine.txt)
cat $T/machine.txt $T/launch.txt $T/bench_host.txt $OUT/fern.txt; grep -A8 '^# ours' $T/peer.txt
