#!/usr/bin/env python3
"""What Dask's MALLOC_TRIM_THRESHOLD_=65536 (set by its nannies in every worker) costs reings' host
side: the same work in a child process with and without the variable. Setting any glibc malloc
threshold turns off glibc's dynamic mmap threshold, so every large numpy temporary is mapped and
page-faulted afresh (reings.cluster._worker_environ drops it for reings' workers).

    python bench/bench_malloc_trim.py [--repeat 10]

Work: reings.metrics.ssim of a 504x378 RGB pair, `repeat` times; a loop of 200 allocate-fill-scale
steps of a 2.3 MB float32 array. One JSON line per setting.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, sys, time
import numpy as np
from reings import metrics
rng = np.random.default_rng(0)
a = rng.random((378, 504, 3), dtype=np.float32); b = rng.random((378, 504, 3), dtype=np.float32)
metrics.ssim(a, b)
t = time.perf_counter()
for _ in range(int(sys.argv[1])):
    metrics.ssim(a, b)
ssim_s = time.perf_counter() - t
t = time.perf_counter()
for _ in range(200):
    x = np.empty(378 * 504 * 3, np.float32); x[:] = 1; y = x * 2
print(json.dumps({"ssim_s": round(ssim_s, 3), "alloc_s": round(time.perf_counter() - t, 3)}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=10, help="SSIM calls timed")
    a = ap.parse_args(argv)
    for trim in (None, "65536"):
        env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
        if trim is not None:
            env["MALLOC_TRIM_THRESHOLD_"] = trim
        out = subprocess.run([sys.executable, "-c", CHILD, str(a.repeat)], env=env, capture_output=True,
                             text=True, check=True).stdout
        row = {"MALLOC_TRIM_THRESHOLD_": trim, "ssim_calls": a.repeat, **json.loads(out)}
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
