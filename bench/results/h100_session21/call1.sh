#!/usr/bin/env bash
# Session 21, call 1: the training step against gsplat 1.5.3 on one H100, same process, same arrays
# (bench/peer_step.py), at HEAD; the wall timings on the default unprofiled queue, then again with
# REINGS_QUEUE_PROFILING=1 for the per-stage device breakdown.
set -u
python3 -m pip install -q --no-index --no-deps --target /tmp/site ../.whl/*.whl ../.whl_gsplat/*.whl
export PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version,memory.used --format=csv > $OUT/gpu.txt
python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json $OUT/peer_unprofiled.jsonl > $OUT/peer_unprofiled.txt 2>&1
REINGS_QUEUE_PROFILING=1 python3 bench/peer_step.py --device cuda --scenes A,B,C --sh 0,3 --json $OUT/peer_profiled.jsonl > $OUT/peer_profiled.txt 2>&1
tail -12 $OUT/peer_unprofiled.txt; tail -12 $OUT/peer_profiled.txt
