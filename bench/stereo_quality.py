#!/usr/bin/env python3
"""How accurate the stereo prior's depth is, per scene and view count, for a set of stereo options.

The prior sees the protocol's training views only. It is scored against:
  * the procedural scene: its exact depths, every pixel;
  * a real scene (LLFF, DTU): a *reference* depth for each training view made by the same stereo
    code from that view and its `--ref-neighbours` nearest other views of the whole capture (small
    baselines, many views), scored on the pixels where the reference is confident (c > 0.6).
    The reference uses views the prior never sees; it exists only to score it, here.

Reported per (scene, views): the median relative depth error |d - d_ref| / d_ref of the filled
depth, the share of pixels within 2 % and within 5 %, and the share the prior marks confident
(c >= 0.3). One JSON line per cell with --json.

    python bench/stereo_quality.py --scenes procedural,llff/fern,llff/flower,dtu/scan24 --views 2,3 \\
        --data-root DATA [--set sgm_p1=0.4,sgm_p2=9.6] [--bounds]
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import re
import time

import numpy as np


def _opts(text: str) -> dict:
    out = {}
    for kv in filter(None, re.split(r",(?=\w+=)", text or "")):  # commas inside tuples stay
        k, v = kv.split("=", 1)
        out[k] = ast.literal_eval(v)  # numbers, tuples
    return out


def reference(scene, i: int, k: int, cache: dict):
    from reings.data.stereo import stereo_depths

    key = (id(scene), i, k)
    if key not in cache:
        C = np.array([np.asarray(c.center) for c in scene.cameras])
        d = np.linalg.norm(C - C[i], axis=1)
        nb = [int(j) for j in np.argsort(d) if j != i][:k]
        r = stereo_depths([scene.images[j] for j in [i] + nb], [scene.cameras[j] for j in [i] + nb],
                          window=9, sgm_p1=0.03, sgm_p2=0.6)[0]
        cache[key] = (r.depth, r.confidence > 0.6)
    return cache[key]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="procedural,llff/fern,llff/flower,dtu/scan24")
    ap.add_argument("--views", default="2,3")
    ap.add_argument("--data-root", default=os.environ.get("REINGS_DATA", ""))
    ap.add_argument("--set", default="", help="stereo options, k=v,k=v (reings.data.stereo.stereo_depths)")
    ap.add_argument("--bounds", action="store_true", help="pass the training views' near/far bounds")
    ap.add_argument("--ref-neighbours", type=int, default=4)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    from reings.data.loader import load_scene
    from reings.data.splits import few_shot_split
    from reings.data.stereo import stereo_depths

    opts = _opts(a.set)
    refcache: dict = {}
    rows = []
    for name in a.scenes.split(","):
        if name == "procedural":
            scene = load_scene(None, "procedural")
        else:
            path = os.path.join(a.data_root, name)
            if not os.path.isdir(path):
                print(f"skip {name}: {path} not found (--data-root or REINGS_DATA)")
                continue
            scene = load_scene(path, "dtu" if name.startswith("dtu") else None)
        for views in (int(v) for v in a.views.split(",")):
            tr, _ = few_shot_split(scene, views)
            train = scene.subset(tr)
            pts = None if getattr(train, "points_from_all_views", False) else train.points
            kw = dict(opts)
            if a.bounds and train.bounds is not None:
                kw["bounds"] = train.bounds
            t = time.perf_counter()
            res = stereo_depths(list(train.images), list(train.cameras), pts, **kw)
            sec = time.perf_counter() - t
            cells = []
            for j, r in enumerate(res):
                if train.depths is not None:
                    gt = np.asarray(train.depths[j], np.float64)
                    m = np.isfinite(gt) & (gt > 0)
                else:
                    gt, m = reference(scene, tr[j], a.ref_neighbours, refcache)
                rel = np.abs(r.depth - gt) / np.where(m, gt, 1.0)
                cells.append((np.median(rel[m]), (rel[m] < 0.02).mean(), (rel[m] < 0.05).mean(),
                              (r.confidence >= 0.3).mean()))
            c = np.mean(cells, axis=0)
            row = {"scene": name, "views": views, "set": opts, "bounds": a.bounds, "seconds": round(sec, 2),
                   "median_rel_err": round(float(c[0]), 4), "within_2pct": round(float(c[1]), 4),
                   "within_5pct": round(float(c[2]), 4), "confident": round(float(c[3]), 4)}
            rows.append(row)
            if a.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"{name:14s} {views}v  median rel err {c[0]:.3f}  <2% {c[1]:.3f}  <5% {c[2]:.3f}  "
                      f"confident {c[3]:.3f}  ({sec:.1f} s)  {a.set or 'defaults'}{' +bounds' if a.bounds else ''}",
                      flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
