set -u
# session 29, call 1 (nvidia-h100-x1). Run from the repository root: bash bench/results/h100_session29/call1.sh .gpu29
# LossConfig.hard_depth_scale (the coarse fit's hard depth pass at half resolution): accuracy at scale 1 and 2 on
# fern, flower (official LLFF) and room (NeX-format LLFF) at 3 views, seeds 0-2, full schedule (paper preset),
# six runs at a time on the one GPU (seconds under that contention are not timings); then the step against
# gsplat 1.5.3 on A, B, C at SH 0 and 3 (alone).
CARRY=$1; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl .whl_gsplat/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd PYTHONPATH=/tmp/site:$R
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/acc; mkdir -p $T
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > $OUT/device.txt
# warm the kernel cache once (one short fit), so the parallel runs do not all build
timeout 120 python3 -m reings.cli eval --dataset llff --root $CARRY/data/llff --scenes fern --views 3 --seeds 0 \
  --methods reings --preset quick --device cuda:0 --no-lpips --out $T/warm > $T/warm.log 2>&1
job() {  # dataset scene seed scale
  timeout 420 python3 -m reings.cli eval --dataset $1 --root $CARRY/data/$1 --scenes $2 --views 3 --seeds $3 \
    --methods reings --preset paper --device cuda:0 --no-lpips --hard-depth-scale $4 --out $T/s$4/$2_$3 > $T/log_$2_$3_s$4.txt 2>&1
}
t0=$(date +%s)
for seed in 0 1 2; do
  for sc in 1 2; do job llff fern $seed $sc & job llff flower $seed $sc & job llff_nex room $seed $sc & done
  wait
done
echo "grid wall $(( $(date +%s) - t0 )) s" > $OUT/grid.txt
python3 - >> $OUT/grid.txt <<'PY'
import glob, json
rows = []
for f in sorted(glob.glob('/tmp/acc/s*/*/**/metrics.json', recursive=True)):
    m = json.load(open(f)); s = m['seconds']
    scale = f.split('/')[3]
    rows.append((m['scene'], m['seed'], scale, m['mean']['psnr'], m['mean']['ssim'],
                 sum(s[k] for k in ('coarse', 'fine', 'final')), m['gaussians'].get('final_prune')))
for r in rows:
    print(*r)
PY
(cd /tmp/acc && tar -czf $OUT/acc_metrics.tgz $(find s1 s2 -name metrics.json) log_*.txt)
timeout 230 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --rounds 3 --json $OUT/peer.jsonl > $OUT/peer.txt 2>&1
cat $OUT/grid.txt; grep -E "ratio|scene" $OUT/peer.txt | tail -12
