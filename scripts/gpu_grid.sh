#!/usr/bin/env bash
# The LLFF result grid on a lent multi-GPU NVIDIA machine (nvidia-h200-x4), in one call:
#   GPU workers (WORKERS_PER_GPU per GPU, pinned to the first half of the cores) share the job list of
#   `reings eval` through its per-run locks: fern, flower x 2/3/4 views x {reings, its three
#   ablations, dngaussian}, full (paper) schedule; then issue 4's baselines at 3 views (dngaussian
#   with 2000 and 8000 random points, 3dgs), the paper-literal IVPS depth, and the model-size study
#   (CVPS keeping 20% instead of 40%; SH degree 1 instead of 3).
#   PoCL (second half of the cores): the full-schedule fern 3-view ReInGS run (3/4 of that half) and the
#   quick preset at 3 views (the rest).
# LPIPS is off here (its 59 MB model does not fit the carry budget beside the data): the test
# renders come back in $OUT and scripts/rescore_lpips.py adds LPIPS on the home machine.
# Runs stop at GRID_SECONDS; rerunning the script on the same warm machine resumes them.
# Carry: .whl and .gpudata (data under .gpudata/llff, depth-prior and SfM caches under .gpudata/cache).
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
GRID=${GRID:-/tmp/grid}; mkdir -p "$GRID"
GRID_SECONDS=${GRID_SECONDS:-540}
WORKERS_PER_GPU=${WORKERS_PER_GPU:-2}
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 REINGS_CACHE_DIR=$PWD/.gpudata/cache
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null
echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
NGPU=$(nvidia-smi -L | wc -l); NCPU=$(nproc)
{ nvidia-smi --query-gpu=name,driver_version --format=csv,noheader; lscpu | grep -E "Model name|^CPU\(s\)"; python3 -m reings.cli devices; } > "$GRID/machine.txt" 2>&1
E="python3 -m reings.cli eval --dataset llff --root .gpudata/llff --scenes fern,flower --no-lpips --quiet --keep-going"
MAIN="--views 2,3,4 --methods reings,reings-no-ehps,reings-no-ivps,reings-no-cvps,dngaussian --preset paper --out $GRID/paper"
half=${GPU_CORES:-$((NCPU / 2))}  # cores 0..half-1 drive the GPUs, the rest run PoCL
POCL_FULL=${POCL_FULL:-1}
w=0
for g in $(seq 0 $((NGPU - 1))); do
  for k in $(seq 1 $WORKERS_PER_GPU); do
    lo=$(( (w * half) / (NGPU * WORKERS_PER_GPU) )); hi=$(( ((w + 1) * half) / (NGPU * WORKERS_PER_GPU) - 1 ))
    EXTRAS="$E --views 3 --methods 3dgs --preset paper --out $GRID/paper --device cuda:$g
        $E --views 3 --methods dngaussian --init-points 2000 --preset paper --out $GRID/pts2000 --device cuda:$g
        $E --views 3 --methods dngaussian --init-points 8000 --preset paper --out $GRID/pts8000 --device cuda:$g
        $E --views 3 --methods reings --ivps-depth hard --preset paper --out $GRID/ivps_hard --device cuda:$g
        $E --views 3 --methods reings --cvps-fraction 0.2 --preset paper --out $GRID/cvps02 --device cuda:$g
        $E --views 3 --methods reings --sh-degree 1 --preset paper --out $GRID/sh1 --device cuda:$g"
    if [ $k = 1 ]; then JOBS="$EXTRAS
        $E $MAIN --device cuda:$g"; else JOBS="$E $MAIN --device cuda:$g
        $EXTRAS"; fi  # one worker takes the short extra runs first
    ( timeout $GRID_SECONDS taskset -c $lo-$hi bash -c "$JOBS" ) >> "$GRID/worker_gpu${g}_$k.log" 2>&1 &
    w=$((w + 1))
  done
done
# PoCL: the full-schedule ReInGS run of fern at 3 views (issue 6: same settings and seed as the GPU
# run in $GRID/paper; resumes from its checkpoints on a second call), and the quick preset at 3 views.
PF=$((half + (NCPU - half) * 3 / 4 - 1))
[ "$POCL_FULL" = 1 ] || PF=$((half - 1))
[ "$POCL_FULL" = 1 ] && ( POCL_CPU_MAX_CU_COUNT=$((PF - half + 1)) timeout $GRID_SECONDS taskset -c $half-$PF \
    python3 -m reings.cli run --data .gpudata/llff/fern --views 3 --device pocl --preset paper --no-lpips --quiet \
    --out $GRID/pocl_full/fern3 ) > "$GRID/worker_pocl_full.log" 2>&1 &
[ $((PF + 1)) -lt $NCPU ] && ( POCL_CPU_MAX_CU_COUNT=$((NCPU - PF - 1)) timeout $GRID_SECONDS taskset -c $((PF + 1))-$((NCPU - 1)) \
    $E --views 3 --methods reings,dngaussian --preset quick --out $GRID/quick_pocl --device pocl ) \
    > "$GRID/worker_pocl_quick.log" 2>&1 &
wait
for d in paper pts2000 pts8000 ivps_hard cvps02 sh1 quick_pocl; do
  [ -d "$GRID/$d" ] && python3 -m reings.cli eval --table-only --out "$GRID/$d" > /dev/null 2>&1
done
cd "$GRID"
tar czf "$OUT/tables_logs.tgz" machine.txt *.log $(find . -name "results.*" -o -name "metrics.json" -o -name "psnr_vs_time.svg" | sort)
[ -d pocl_full/fern3/renders ] && tar czf "$OUT/pocl_full.tgz" pocl_full/fern3/renders pocl_full/fern3/metrics.json 2>/dev/null
for s in fern flower; do  # one archive per scene x views: each stays under the 16 MB per-file limit
  for v in 2 3 4; do
    f=$(find . -path "*/${v}views/$s/renders/*.png" | sort)
    [ -n "$f" ] && tar czf "$OUT/renders_${s}_${v}.tgz" $f
  done
done
ls -la "$OUT"; tail -n 2 worker_*.log
