set -u
# session 36, call 2: call 1's fern runs took 29.92 / 27.23 s against session 35's 27.12 / 26.15 s. An alternating A/B on
# one machine: the tree before this session (5013dc6, in .old36) and this session's, fern seeds 0 and 1 in the order old, new, new, old.
# Run from the repository root: bash bench/results/h100_session36/call2.sh .gpu30 .old36
CARRY=$1; OLD=$2; R=$PWD
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p /tmp/icd && cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null; echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
export OCL_ICD_VENDORS=/tmp/icd
mkdir -p /tmp/cache; cp -r $CARRY/cache/* /tmp/cache/; export REINGS_CACHE_DIR=/tmp/cache PYTHONUNBUFFERED=1 PATH=/tmp/site/bin:$PATH
T=/tmp/timing2; mkdir -p $T
EV="eval --dataset llff --root $R/$CARRY/data/llff --scenes fern --views 3 --methods reings --preset paper --device cuda:0 --no-lpips"
for tree in old new; do
  [ $tree = old ] && export PYTHONPATH=/tmp/site:$R/$OLD || export PYTHONPATH=/tmp/site:$R
  timeout 60 python3 -m reings.cli $EV --seeds 0 --iterations 30,30,30 --out $T/warm_$tree > $T/warm_$tree.txt 2>&1
done
for rep in 1; do for tree in old new new old; do for sd in 0 1; do
  [ $tree = old ] && export PYTHONPATH=/tmp/site:$R/$OLD || export PYTHONPATH=/tmp/site:$R
  o=$T/${tree}_${rep}_${sd}_$RANDOM; timeout 100 python3 -m reings.cli $EV --seeds $sd --out $o > $o.txt 2>&1
  f=$(ls $o/llff/reings/3views/*/metrics.json | head -1)
  python3 -c "import json,sys; m=json.load(open(sys.argv[1])); s=m['seconds']; print(sys.argv[3], 'seed', sys.argv[2], round(m['mean']['psnr'],6), 'training', round(sum(s[k] for k in ('coarse','fine','final')),2), [round(s[k],2) for k in ('coarse','fine','final')], 'end to end', round(s.get('total', 0), 2))" $f $sd $tree | tee -a $OUT/ab.txt
done; done; done
