set -u
# session 25, call 1 (nvidia-h100-x1). Run from the repository root: bash call1.sh .gpu_s24
# (a) peer_step A,B,C, SH 0 / 3, 3 rounds (NEW = bd61f61); (b) fern 3v seed 0 full schedule under host_wait: OLD (.gpu_old = eee68ce, code cbab11e)
# and NEW (.gpu_clean = HEAD), alternating, three pairs.
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; grep -A12 '^# ours' $T/peer.txt 2>/dev/null | head -13; for f in $T/hw_*.txt; do echo "== $f"; cat $f; done 2>/dev/null; } > $OUT/timing.txt; }
cp $R/.gpu_clean/bench/host_wait.py $R/.gpu_old/bench/host_wait.py
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD timeout 200 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $T/peer.txt 2>&1)
out
run() {
  name=$1; tree=$2
  S=$R/$tree
  (cd $S && PYTHONPATH=/tmp/site:$S timeout 110 python3 bench/host_wait.py --out $T/$name.json -- eval \
    --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --seeds 0 --methods reings --preset paper \
    --device cuda:0 --no-lpips --out $T/$name 2>&1 | grep -v "^WARNING: Target" | tail -6 > $T/hw_$name.txt)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), 'end to end', round(s.get('total', 0), 2))" \
    $T/$name/llff/reings/3views/fern/metrics.json >> $T/hw_$name.txt 2>&1
  out
}
run new_1 .gpu_clean; run old_1 .gpu_old; run new_2 .gpu_clean; run old_2 .gpu_old; run new_3 .gpu_clean; run old_3 .gpu_old
cp $T/peer.txt $OUT/ 2>/dev/null
tar -czf $OUT/host_wait.tgz -C $T $(cd $T && ls *.json)
cat $OUT/timing.txt
