set -u
# session 26: wait until every run of /tmp/g has finished or WAIT_S seconds have passed, then print the finished
# runs (and with PACK=1 pack /tmp/g into $OUT). Usage: bash bench/results/h100_session26/status.sh WAIT_S [PACK]
WAIT=$1; PACK=${2:-0}; t0=$(date +%s)
while [ $(( $(date +%s) - t0 )) -lt $WAIT ]; do
  [ -f /tmp/g/done.txt ] && [ "$(wc -l < /tmp/g/done.txt)" -ge "$(cat /tmp/g/total.txt)" ] && break
  sleep 10
done
echo "done $(wc -l < /tmp/g/done.txt 2>/dev/null || echo 0) of $(cat /tmp/g/total.txt) after $(( $(date +%s) - t0 )) s waiting"
cat /tmp/g/done.txt 2>/dev/null
nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader
for f in $(find /tmp/g -name metrics.json | sort); do python3 -c "
import json; m=json.load(open('$f')); e=m.get('ensemble') or {}
print('$f'.split('/')[3], m['scene'], m['views'], m['seed'], round(m['mean']['psnr'],3), round(m['mean']['ssim'],4),
      'members', [round(p['psnr'],3) for p in e.get('per_member',[])], e.get('gaussians'), round(m['seconds']['method'],1), round(m['seconds']['total'],1))"; done
if [ "$PACK" = 1 ]; then printf 'd3A\nd3B\nd3C\nd2A\nd4A\nd2B\nd4B\n' > /tmp/g/pack_order.txt; python3 scripts/pack_out.py /tmp/g $OUT --max-files 8; fi
