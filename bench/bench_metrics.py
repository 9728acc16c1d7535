"""Seconds per image pair of each metric at LLFF factor-8 size (378x504), on the CPU.

    python bench/bench_metrics.py [--repeat 5] [--json OUT.jsonl]

Uses two fern images when REINGS_DATA holds llff/fern, else two procedural views. LPIPS needs
lpips_vgg.onnx (REINGS_LPIPS_MODEL, or the user cache; reings.metrics.find_lpips_model); it is skipped with a note if absent.
Pin the process (e.g. `taskset -c 0,1`) to measure a 2-core laptop-class budget.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np


def _pair():
    root = os.environ.get("REINGS_DATA")
    if root and os.path.isdir(os.path.join(root, "llff", "fern")):
        from reings import load_scene

        sc = load_scene(os.path.join(root, "llff", "fern"), factor=8)
        return "fern image000 vs image008", sc.images[0], sc.images[8]
    from reings import make_procedural_scene

    sc = make_procedural_scene()
    return "procedural views 0 vs 1", sc.images[0], sc.images[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from reings import metrics

    what, x, y = _pair()
    fns = {"psnr": lambda: metrics.psnr(x, y), "ssim_gs": lambda: metrics.ssim(x, y, kind="gs"),
           "lpips_vgg": lambda: metrics.lpips(x, y)}
    rows = []
    for name, f in fns.items():
        try:
            v = f()  # warm-up (loads the ONNX session once)
        except Exception as e:  # no LPIPS model here
            print(f"{name}: skipped ({type(e).__name__}: {e})")
            continue
        ts = []
        for _ in range(a.repeat):
            t = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t)
        row = {"metric": name, "pair": what, "shape": list(x.shape), "value": float(v),
               "s_min": min(ts), "s_median": float(np.median(ts)), "cpus": len(os.sched_getaffinity(0)),
               "cpu": platform.processor() or platform.machine()}
        rows.append(row)
        print(f"{name:10s} {row['value']:.4f}  min {row['s_min']*1e3:8.1f} ms  median {row['s_median']*1e3:8.1f} ms"
              f"  ({row['cpus']} cpus, {what})")
    if a.json:
        with open(a.json, "a") as fh:
            for r in rows:
                fh.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
