set -u
# session 11, call 2: the new kernels' tests on NVIDIA OpenCL (DropGaussian in project.cl, the metric
# depth term) next to the full-schedule runs of runs2.txt
mkdir -p /tmp/g
(sleep 40; PYTHONPATH=/tmp/site:$PWD REINGS_TEST_DEVICES=cuda timeout 400 python3 -m pytest -q -p no:cacheprovider \
   tests/test_drop.py tests/test_depth_metric.py tests/test_project.py -k "not oclgrind" > /tmp/g/pytest_cuda_new_kernels.log 2>&1) &
bash bench/results/h100_session11/call_runs.sh .gpu_c2 520 bench/results/h100_session11/runs2.txt
