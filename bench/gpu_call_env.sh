# Shared scaffolding of a device call (docs/perf_notes.md, "GPU calls"): source it from a call's script,
#   source bench/gpu_call_env.sh CARRY [GUARD_S]
# CARRY: the carried folder holding data/<dataset>/<scene> and cache/ (the SfM and depth caches filled here with
# `reings eval --prepare-only`); GUARD_S: no run starts after this many seconds of the call (default 540).
# It installs the carried wheels (.whl/), writes the NVIDIA ICD file, copies the caches to /tmp, and defines
#   one TAG DATASET SCENE VIEWS SEED PRESET [options...]   one `reings eval` on cuda:0 into $RUNS/TAG
#                                                          (its console in $RUNS/TAG_SCENE_VIEWS_SEED.txt);
#                                                          in the background when PAR > 1, at most PAR at once
#   finish                                                 wait for the runs, write $OUT/runs.txt (one line a
#                                                          run: bench/gpu_runs_table.py) and $OUT/tails.txt
CARRY=$1; GUARD=${2:-540}; R=$PWD; T0=$(date +%s); PAR=${PAR:-1}
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl 2>/dev/null
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1
export PATH=/tmp/site/bin:$PATH
mkdir -p /tmp/cache && cp -r "$CARRY"/cache/* /tmp/cache/
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > "$OUT/gpu.txt"
RUNS=/tmp/runs; mkdir -p $RUNS

one() {
  local tag=$1 ds=$2 sc=$3 v=$4 s=$5 pr=$6; shift 6
  if [ $(( $(date +%s) - T0 )) -gt "$GUARD" ]; then echo "skipped (guard): $tag $sc $v $s" >> "$OUT/skipped.txt"; return; fi
  while [ "$(jobs -rp | wc -l)" -ge "$PAR" ]; do wait -n; done
  timeout $(( 600 - GUARD > 60 ? 600 - GUARD : 60 )) python3 -m reings.cli eval --dataset "$ds" --root "$R/$CARRY/data/$ds" \
    --scenes "$sc" --views "$v" --seeds "$s" --methods reings --preset "$pr" --device cuda:0 --no-lpips \
    --out "$RUNS/$tag" "$@" > "$RUNS/${tag}_${sc}_${v}_$s.txt" 2>&1 &
  [ "$PAR" -gt 1 ] || wait
}

finish() {
  wait
  python3 "$R/bench/gpu_runs_table.py" "$RUNS" > "$OUT/runs.txt"
  tail -n 2 "$RUNS"/*.txt > "$OUT/tails.txt"
  cat "$OUT/runs.txt"
}
