set -u
# session 22, call 1 (nvidia-h100-x1). Run from the repository root: bash call1.sh .gpu_s24
# OLD = 0aaeab7 (.gpu_old); NEW = the densification's surgery on the device (.gpu_clean: Trainer.read_columns /
# apply_rows / reset_opacity, kernels/gather_rows.cl with zeros for new rows; the same bits as OLD on PoCL).
# (a) the row-edit tests and the device-vs-host fits on NVIDIA; (b) fern 3v seed 0 full schedule OLD, NEW, NEW, OLD;
# (c) one --profile run each (the densify phase).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
T=/tmp/timing; mkdir -p $T
out() { { nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; cat $T/tests.txt $T/summary.txt $T/phases.txt 2>/dev/null; } > $OUT/timing.txt; }
src() { case $1 in OLD) echo "$R/.gpu_old";; *) echo "$R/.gpu_clean";; esac; }
(cd .gpu_clean && PYTHONPATH=/tmp/site:$PWD REINGS_TEST_DEVICES=cuda timeout 200 python3 -m pytest -q tests/test_apply_rows.py tests/test_device_fit.py tests/test_prune_unseen.py tests/test_background.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -3) > $T/tests.txt
out
run() {
  name=$1; s=$(src $2); shift 2
  (cd $s && PYTHONPATH=/tmp/site:$s timeout 100 python3 -m reings.cli eval --dataset llff --root $R/$CARRY/data/llff --scenes fern \
    --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out $T/$name "$@" 2>&1 \
    | grep -v "^WARNING: Target" > $T/$name.log)
  f=$T/$name/llff/reings/3views/fern/metrics.json
  [ -f $f ] && python3 - "$name" "$f" >> $T/summary.txt <<'PY'
import json, sys
name, f = sys.argv[1], sys.argv[2]
m = json.load(open(f))
s = m["seconds"]
tr = sum(s[k] for k in ("coarse", "fine", "final"))
print(name, round(m["mean"]["psnr"], 6), "training", round(tr, 2), {k: round(v, 2) for k, v in s.items() if isinstance(v, (int, float))})
for st in m.get("stages", []):
    ph = st.get("phases")
    if ph:
        print("  ", st.get("stage"), {k: round(v, 3) for k, v in sorted(ph.items(), key=lambda kv: -kv[1])[:8] if isinstance(v, (int, float))}, "densify", round(ph.get("densify", 0), 3))
PY
  out
}
run OLD_1 OLD; run NEW_1 NEW; run NEW_2 NEW; run OLD_2 OLD
run OLD_prof OLD --profile; run NEW_prof NEW --profile
cp $T/*.log $OUT/ 2>/dev/null; tar -czf $OUT/metrics.tgz -C $T $(cd $T && ls -d */ | tr -d /) 2>/dev/null
out
cat $OUT/timing.txt
