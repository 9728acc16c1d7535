set -u
# session 26, call 4 (nvidia-h100-x1): an ensemble's members one after another (--ensemble-jobs 1) or at once
# (--ensemble-jobs 2: member 1 in a worker process on the same GPU; a GPU default when this ran, off since); DTU scan24 and fern, 3 views,
# seed 0, alone on the GPU, alternating. CARRY = $1 (.gpu_s26).
CARRY=$1
mkdir -p /tmp/cache /tmp/g; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > /tmp/g/machine.txt; nproc >> /tmp/g/machine.txt
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
for spec in "dtu scan24 2 a" "dtu scan24 1 a" "dtu scan24 2 b" "llff fern 2 a" "llff fern 1 a"; do
  set -- $spec
  t=$(date +%s.%N)
  bash scripts/lent_gpu.sh eval --dataset $1 --root $CARRY/data/$1 --scenes $2 --views 3 --seeds 0 --methods reings \
    --preset paper --device cuda:0 --no-lpips --ensemble 2 --ensemble-jobs $3 --out /tmp/g/$2_j$3$4 --quiet \
    < /dev/null > /tmp/g/$2_j$3$4.log 2>&1
  echo "$2 jobs $3 ($4): $(python3 -c "print(round($(date +%s.%N) - $t, 1))") s wall" | tee -a /tmp/g/wall.txt
done
for f in $(find /tmp/g -name metrics.json | sort); do python3 -c "
import json; m=json.load(open('$f')); e=m['ensemble']
print('$f'.split('/')[3], round(m['mean']['psnr'],4), [round(p['psnr'],4) for p in e['per_member']], [round(p['seconds'],1) for p in e['per_member']], 'method', round(m['seconds']['method'],1), 'total', round(m['seconds']['total'],1))"; done | tee /tmp/g/summary.txt
cd /tmp/g && tar czf $OUT/call4.tgz $(find . -name metrics.json) *.txt *.log
