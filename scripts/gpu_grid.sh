#!/usr/bin/env bash
# Result grids on a lent NVIDIA machine (one or more GPUs), in one call, from job files:
#
#   scripts/gpu_grid.sh GPU_JOBS [POCL_JOBS]
#
# Each non-comment line of a job file holds the arguments of one `reings eval` over the LLFF
# scenes under .gpudata/llff, after the common ones (--dataset llff --root .gpudata/llff --no-lpips
# --quiet --keep-going); a relative --out is taken under $GRID. Every GPU worker (WORKERS_PER_GPU
# per GPU, PER = GPU_CORES / workers cores each, within
# cores 0..GPU_CORES-1, default 2 per worker) walks the whole GPU file in order with --device cuda:g;
# every PoCL worker (POCL_SLICES slices of POCL_CORES cores after those) walks the PoCL file with
# --device pocl. Workers share the runs through `reings eval`'s per-run locks, so list long runs
# first. LPIPS is off (the 59 MB VGG model does not fit the carry budget beside the data): the
# test renders come back in $OUT (scripts/pack_out.py) and scripts/rescore_lpips.py adds LPIPS
# on the home machine. Workers stop at GRID_SECONDS.
# Carry: .whl and .gpudata (LLFF scenes under .gpudata/llff; depth-prior and SfM caches under
# .gpudata/cache: fill them first with `reings eval ... --prepare-only`).
set -u
GJOBS=${1:?usage: scripts/gpu_grid.sh GPU_JOBS [POCL_JOBS]}; PJOBS=${2:-}
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
GRID=${GRID:-/tmp/grid}; mkdir -p "$GRID"
GRID_SECONDS=${GRID_SECONDS:-540}
WORKERS_PER_GPU=${WORKERS_PER_GPU:-4}
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=$PWD/.gpudata/cache
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
NGPU=$(nvidia-smi -L | wc -l); NCPU=$(nproc)
NW=$((NGPU * WORKERS_PER_GPU))
GPU_CORES=${GPU_CORES:-$((2 * NW))}
PER=$(( GPU_CORES / NW )); [ "$PER" -lt 1 ] && PER=1
POCL_CORES=${POCL_CORES:-4}
POCL_SLICES=${POCL_SLICES:-$(( (NCPU - GPU_CORES) / POCL_CORES ))}
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"
  python3 -m reings.cli devices; echo "GPU workers $NW on cores 0-$((GPU_CORES - 1));" \
  "PoCL workers $POCL_SLICES x $POCL_CORES cores"; } > "$GRID/machine.txt" 2>&1
cp "$GJOBS" "$GRID/gpu_jobs.txt"; [ -n "$PJOBS" ] && cp "$PJOBS" "$GRID/pocl_jobs.txt"
cp "${PACK_ORDER:-scripts/grids/pack_order.txt}" "$GRID/pack_order.txt" 2>/dev/null  # which renders come back first

# worker JOBFILE DEVICE: every line of JOBFILE as one `reings eval`, in order
worker() {
  grep -v '^\s*#' "$1" | grep -v '^\s*$' | while read -r line; do
    out=$(sed -E 's/.*--out +([^ ]+).*/\1/' <<< "$line")
    line=${line/--out $out/--out $GRID/$out}
    python3 -m reings.cli eval --dataset llff --root .gpudata/llff --no-lpips --quiet --keep-going \
      $line --device "$2" < /dev/null
  done
}
export -f worker; export GRID
w=0
for g in $(seq 0 $((NGPU - 1))); do
  for k in $(seq 1 "$WORKERS_PER_GPU"); do
    lo=$(( (w * PER) % GPU_CORES )); hi=$(( lo + PER - 1 ))
    ( timeout "$GRID_SECONDS" taskset -c "$lo-$hi" bash -c "worker $GRID/gpu_jobs.txt cuda:$g" ) \
      >> "$GRID/worker_gpu${g}_$k.log" 2>&1 &
    w=$((w + 1))
  done
done
if [ -n "$PJOBS" ]; then
  for s in $(seq 0 $((POCL_SLICES - 1))); do
    lo=$(( GPU_CORES + s * POCL_CORES )); hi=$(( lo + POCL_CORES - 1 ))
    ( POCL_CPU_MAX_CU_COUNT=$POCL_CORES timeout "$GRID_SECONDS" taskset -c "$lo-$hi" \
      bash -c "worker $GRID/pocl_jobs.txt pocl" ) >> "$GRID/worker_pocl_$s.log" 2>&1 &
  done
fi
wait
for d in $(cat "$GRID/gpu_jobs.txt" "$GRID/pocl_jobs.txt" 2>/dev/null | grep -v '^\s*#' \
           | sed -nE 's/.*--out +([^ ]+).*/\1/p' | sort -u); do
  [ -d "$GRID/$d" ] && python3 -m reings.cli eval --table-only --out "$GRID/$d" > /dev/null 2>&1
done
python3 scripts/pack_out.py "$GRID" "$OUT"
ls -la "$OUT"; tail -qn 1 "$GRID"/worker_*.log
