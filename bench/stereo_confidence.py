#!/usr/bin/env python3
"""How well the stereo prior's confidence predicts its depth error, on the procedural scene (the one
scene here with exact depths): per training view, the share of pixels and the median relative depth
error |d - d_exact| / d_exact in confidence bins. The stereo prior fills low-confidence pixels
(push-pull + guided filter) and marks them c = 0.

    python bench/stereo_confidence.py [--views 2,3]

Measured 2026-11-25 (docs/results.md §12): c = 0 covers 44-47 % of the pixels at 2 views and 14-30 %
at 3, with a median relative error of 0.11-0.26; c >= 0.6 covers 46-52 % at 0.006-0.008.
"""
from __future__ import annotations

import argparse

import numpy as np

BINS = ((0.0, 0.0), (0.0, 0.3), (0.3, 0.6), (0.6, 1.0))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--views", default="2,3", help="training view counts, comma-separated")
    a = ap.parse_args(argv)
    from reings.data.depth_prior import get_depth_prior
    from reings.data.loader import load_scene
    from reings.data.splits import few_shot_split

    scene = load_scene(None, "procedural")
    print("views view | " + " | ".join(f"c {'= 0' if hi == 0 else f'in ({lo}, {hi}]'}: px %, median rel err"
                                      for lo, hi in BINS))
    for views in (int(v) for v in a.views.split(",")):
        tr, _ = few_shot_split(scene, views)
        train = scene.subset(tr)
        depths, confs = get_depth_prior("stereo").compute(train, return_confidence=True)
        for i, (d, c) in enumerate(zip(depths, confs)):
            gt = np.asarray(train.depths[i], np.float64)
            ok = np.isfinite(gt) & (gt > 0)
            rel = np.abs(d - gt) / np.where(ok, gt, 1.0)
            cells = []
            for lo, hi in BINS:
                m = ok & ((c <= 0) if hi == 0 else (c > lo) & (c <= hi))
                err = float(np.median(rel[m])) if m.any() else float("nan")
                cells.append(f"{100 * m.mean():5.1f} %, {err:.3f}")
            print(f"{views:5d} {i:4d} | " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
