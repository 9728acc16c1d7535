#!/usr/bin/env python3
"""Pack a grid's results into the few files a lent GPU call can return.

    python scripts/pack_out.py GRID OUT [--max-files 8] [--max-mb 15.5] [--total-mb 62]

Writes OUT/tables_logs.tgz (every metrics.json, results.*, psnr_vs_time.svg, *.log, census*.json
(bench/kernel_census.py) and machine.txt under GRID) and then the runs' 8-bit test renders (what scripts/rescore_lpips.py
needs for LPIPS) into OUT/renders_K.tar chunks of at most --max-mb each, run by run in the order
of GRID's top-level folders as listed in GRID/pack_order.txt (one name per line; folders not
listed come last, alphabetically). A run whose renders do not fit is left out whole and named in
OUT/left_out.txt. The device tool returns at most 8 files of 16 MB, 64 MB in all.
"""
from __future__ import annotations

import argparse
import io
import os
import sys
import tarfile


def _runs(grid: str) -> list[str]:
    """Run folders (those with renders/) under GRID, grouped by top-level folder in pack order."""
    order_file = os.path.join(grid, "pack_order.txt")
    order = []
    if os.path.exists(order_file):
        order = [ln.strip() for ln in open(order_file) if ln.strip()]
    tops = sorted(d for d in os.listdir(grid) if os.path.isdir(os.path.join(grid, d)))
    tops = [t for t in order if t in tops] + [t for t in tops if t not in order]
    runs = []
    for t in tops:
        for root, dirs, _files in sorted(os.walk(os.path.join(grid, t))):
            dirs.sort()
            if "renders" in dirs:
                runs.append(root)
    return runs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("grid")
    ap.add_argument("out")
    ap.add_argument("--max-files", type=int, default=8)
    ap.add_argument("--max-mb", type=float, default=15.5)
    ap.add_argument("--total-mb", type=float, default=62.0)
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    keep = ("metrics.json", "results.md", "results.json", "psnr_vs_time.svg", "machine.txt")
    with tarfile.open(os.path.join(a.out, "tables_logs.tgz"), "w:gz") as tf:
        for root, _dirs, files in sorted(os.walk(a.grid)):
            for f in sorted(files):
                if f in keep or f.endswith(".log") or (f.startswith("census") and f.endswith(".json")):
                    p = os.path.join(root, f)
                    tf.add(p, os.path.relpath(p, a.grid))
    used = os.path.getsize(os.path.join(a.out, "tables_logs.tgz"))
    cap, total_cap = int(a.max_mb * 2**20), int(a.total_mb * 2**20)
    chunks: list[list[tuple[str, str]]] = [[]]
    sizes = [0]
    left = []
    for run in _runs(a.grid):
        rd = os.path.join(run, "renders")
        files = [(os.path.join(rd, f), os.path.relpath(os.path.join(rd, f), a.grid))
                 for f in sorted(os.listdir(rd)) if f.endswith(".png")]
        sz = sum(os.path.getsize(p) for p, _ in files) + 1024 * len(files)
        if sizes[-1] + sz > cap:
            if len(chunks) + 1 >= a.max_files:  # one file is tables_logs.tgz
                left.append(os.path.relpath(run, a.grid))
                continue
            chunks.append([])
            sizes.append(0)
        if used + sum(sizes) + sz > total_cap or sz > cap:
            left.append(os.path.relpath(run, a.grid))
            continue
        chunks[-1].extend(files)
        sizes[-1] += sz
    for k, files in enumerate(c for c in chunks if c):
        with tarfile.open(os.path.join(a.out, f"renders_{k}.tar"), "w") as tf:
            for p, arc in files:
                tf.add(p, arc)
    with open(os.path.join(a.out, "left_out.txt"), "w") as fh:
        fh.write("".join(r + "\n" for r in left))
    print(f"packed {sum(len(c) for c in chunks)} renders in {sum(1 for c in chunks if c)} chunks; "
          f"{len(left)} runs left out", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
