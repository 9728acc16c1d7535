set -u
# session 26: start the runs of LANES detached (setsid: they outlive this call) and return.
# Usage: bash bench/results/h100_session26/queue.sh CARRY LANES
# LANES lines: LANE GPU NAME DATASET SCENE VIEWS SEED [extra reings eval options]; each lane runs its lines one
# after another, all lanes at once (4 per GPU). /tmp/g/done.txt gets one line per finished run.
CARRY=$1; LANES=$2
mkdir -p /tmp/cache /tmp/g; cp -r $CARRY/cache/* /tmp/cache/
export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version,uuid --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
grep -v '^#' $LANES | grep -c . > /tmp/g/total.txt
for lane in $(grep -v '^#' $LANES | awk '{print $1}' | sort -un); do
  ( grep -v '^#' $LANES | awk -v l=$lane '$1==l' | while read -r ln gpu name ds scene views seed extra; do
      t=$(date +%s)
      timeout 1700 bash scripts/lent_gpu.sh eval --dataset $ds --root $CARRY/data/$ds --scenes $scene --views $views \
        --seeds $seed --methods reings --preset paper --device cuda:$gpu --no-lpips --out /tmp/g/$name $extra \
        < /dev/null 2>&1 | grep -v "^WARNING: Target" > /tmp/g/$name.$scene.$views.$seed.log
      echo "$name $scene $views $seed gpu$gpu lane$ln $(( $(date +%s) - t )) s" >> /tmp/g/done.txt
    done ) &
done
wait
