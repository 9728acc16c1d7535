#!/usr/bin/env bash
# The wheels the lent GPU machine needs (it has no package index; Python 3.12 with numpy, scipy,
# onnxruntime, opencv): fetched here into .whl/ (git-ignored via .git/info/exclude), carried with
# `carry: [".whl", ...]`, installed there with
#   python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl
# `cluster` adds dask.distributed and its dependencies (for `reings eval --cluster` there).
set -euo pipefail
cd "$(dirname "$0")/.."
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo /.whl/ >> .git/info/exclude
PKGS="pyopencl pytools platformdirs siphash24 mako tqdm pytest pluggy iniconfig packaging"
[ "${1:-}" = cluster ] && PKGS="$PKGS dask distributed cloudpickle toolz partd locket fsspec tornado msgpack psutil
  sortedcontainers tblib zict click pyyaml jinja2 markupsafe urllib3 importlib-metadata zipp"
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d .whl $PKGS
du -sh .whl
