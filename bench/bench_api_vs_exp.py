#!/usr/bin/env python3
"""Issue 15's CPU yardstick: forward + backward of benchmark scene A (100k Gaussians, 504x378, SH 0)
through the public API (`backend.render` then `backend.render_vjp`), against `np.exp` over 85.5M
float32 values timed in the same process (a memory-bound pass the machine's numpy does at its own
speed, so the ratio travels between machines). Goal: ratio <= 4.

    python bench/bench_api_vs_exp.py [--device pocl] [--repeats 5] [--json FILE]

Minimum and median of `--repeats` timed calls after one warm-up; np.exp is timed before and after
the renders and the faster of the two medians is used.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np


def _timed(f, repeats: int) -> tuple[float, float]:
    f()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return min(ts), float(np.median(ts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None, help="append one JSON line here")
    a = ap.parse_args(argv)
    from reings.backends import get_backend
    from reings.bench_scenes import perf_scene

    be = get_backend(a.device)
    g, cam = perf_scene("A")
    v_rgb = np.random.default_rng(1).standard_normal((cam.height, cam.width, 3)).astype(np.float32)
    x = np.random.default_rng(0).standard_normal(85_500_000).astype(np.float32)

    def fwd_bwd():
        be.render(g, cam)
        be.render_vjp(g, cam, v_rgb)

    exp_before = _timed(lambda: np.exp(x), a.repeats)
    api = _timed(fwd_bwd, a.repeats)
    exp_after = _timed(lambda: np.exp(x), a.repeats)
    exp_med = min(exp_before[1], exp_after[1])
    rec = {"bench": "api_vs_exp", "device": a.device, "device_name": getattr(be, "device_name", a.device),
           "machine": platform.processor() or platform.machine(), "gaussians": len(g),
           "api_min_s": api[0], "api_median_s": api[1], "exp_median_s": exp_med,
           "ratio": api[1] / exp_med, "goal": 4.0}
    print(f"{a.device}: render + render_vjp of scene A {api[1] * 1e3:.1f} ms (min {api[0] * 1e3:.1f}), "
          f"np.exp over 85.5M float32 {exp_med * 1e3:.1f} ms: ratio {rec['ratio']:.2f} (goal <= 4)")
    if a.json:
        with open(a.json, "a") as fh:
            fh.write(json.dumps(rec) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
