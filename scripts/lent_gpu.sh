#!/usr/bin/env bash
# `reings ...` on a lent GPU machine that has no package index: install the carried wheels
# (scripts/gpu_wheels.sh [cluster] fills .whl/) into /tmp/site once, then run the command.
# reings registers NVIDIA's OpenCL library itself when the container has no ICD file for it.
# usage: bash scripts/lent_gpu.sh eval --dataset llff ... --device cuda --cluster local --runs-per-gpu 6
set -eu
ROOT=$(cd "$(dirname "$0")/.." && pwd)
if [ ! -d /tmp/site/pyopencl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$ROOT"/.whl/*.whl
fi
export PYTHONPATH=/tmp/site:$ROOT PYTHONUNBUFFERED=1
exec python3 -m reings.cli "$@"
