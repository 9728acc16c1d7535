cd /work/main
for seed in 0 1 2; do
  for m in dngaussian reings; do
    if [ $m = reings ]; then IT="100,100,300"; else IT="300"; fi
    .venv/bin/reings run --device pocl --preset quick --method $m --seed $seed --iterations $IT --out /tmp/s30/half_${m}_$seed --quiet --overwrite --no-lpips > /tmp/s30/half_${m}_$seed.txt 2>&1
    python3 -c "import json;m=json.load(open('/tmp/s30/half_${m}_$seed/metrics.json'));print('$m', $seed, m['mean']['psnr'], m.get('seconds'))"
  done
done
