set -u
# session 20, call 6 (nvidia-h100-x1, one H100 alone). CARRY = $1 (.gpu_s24).
# OLD = 8acc23e (../.gpu_old); NEW = this tree: the densification's prune of unseen Gaussians gathered on the device
# (Trainer.keep_rows, kernels/gather_rows.cl) instead of a second upload of the state. The same bits.
# (a) tests on NVIDIA; (b) fern 3v seed 0 full schedule OLD, NEW, NEW, OLD; (c) NEW with --profile (densify phase).
CARRY=$1
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/summary.txt $T/phases.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$PWD/../.gpu_old";; *) echo "$PWD";; esac; }
(REINGS_TEST_DEVICES=cuda timeout 150 python3 -m pytest -q tests/test_keep_rows.py tests/test_prune_unseen.py -p no:cacheprovider 2>&1 | tail -2) > $T/tests.txt
out
run() {
  name=$1; g=$2; s=$(src $g); shift 2
  (cd $s && PYTHONPATH=/tmp/site:$s timeout 100 python3 -m reings.cli eval --dataset llff --root $OLDPWD/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name "$@" 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 -c "import json; m=json.load(open('$f')); s=m['seconds']; print('$name', round(m['mean']['psnr'],6), {k: round(v,1) for k,v in s.items() if isinstance(v,(int,float))})" >> $T/summary.txt
  out
}
run OLD_1 OLD; run NEW_1 NEW; run NEW_2 NEW; run OLD_2 OLD
run PROF NEW --profile
python3 - >> $T/phases.txt <<'PY'
import json
m = json.load(open("/tmp/timing/PROF/llff/reings/3views/fern/metrics.json"))
for st in m.get("stages", []):
    ph = st.get("phases")
    if ph:
        print(st.get("stage"), {k: round(v, 3) for k, v in sorted(ph.items(), key=lambda kv: -kv[1]) if isinstance(v, (int, float))})
PY
out
cat $OUT/timing.txt
