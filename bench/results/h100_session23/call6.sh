set -u
# session 23, call 6 (nvidia-h100-x1). Run from the repository root: bash call6.sh
# Tree: .gpu_clean (the re-read: SEL and any8 in common.h). The rasterizer, projection and loss tests on NVIDIA.
S=$PWD/.gpu_clean
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
cd $S && PYTHONPATH=/tmp/site:$S REINGS_TEST_DEVICES=cuda timeout 300 python3 -m pytest -q tests/test_rasterize.py \
  tests/test_project.py tests/test_losses.py -m "not oclgrind" -p no:cacheprovider 2>&1 | tail -3 | tee $OUT/tests.txt
