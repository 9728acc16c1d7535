"""Fly-through rendering speed (issue 13): frames per second of a camera path, encoding excluded.

    python bench/bench_render_path.py --device pocl [--run RUN_DIR] [--gaussians 30000]
        [--frames 120] [--size 504x378] [--path spiral] [--json OUT.jsonl]

Without --run the model is synthetic: N Gaussians spread through the view frustum of LLFF-like
forward-facing cameras between depths 2 and 8 (scales ~1 % of the depth, opacities 0.3-0.95,
SH degree 3), a stand-in for a trained LLFF model of that size. With --run, the run's own model
and cameras. The first frame (kernel build, buffer allocation) is rendered once before timing.
Reported: frames/s over the path (render + read-back of the 8-bit frames, as `reings render`
measures it), and the device.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def synthetic(n: int, seed: int = 0):
    import reings
    from reings.paths import look_at

    rng = np.random.default_rng(seed)
    z = rng.uniform(2, 8, n)
    x = rng.uniform(-0.6, 0.6, n) * z
    y = rng.uniform(-0.45, 0.45, n) * z
    g = reings.Gaussians(means=np.stack([x, y, z], 1), quats=rng.normal(size=(n, 4)),
                         log_scales=np.log(0.01 * z)[:, None] + rng.normal(0, 0.4, (n, 3)),
                         opacity_logits=np.log(1 / rng.uniform(0.3, 0.95, n) - 1) * -1,
                         sh=rng.normal(0, 0.3, (n, 16, 3)))
    K = np.array([[407.0, 0, 252], [0, 407.0, 189], [0, 0, 1]])
    cams = [look_at(np.array([dx, dy, 0.0]), np.array([0.0, 0.0, 5.0]), np.array([0, -1.0, 0]), K, 504, 378)
            for dx, dy in ((-0.2, 0.0), (0.0, 0.05), (0.2, -0.03), (0.1, 0.04))]
    return g, cams


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--run", default=None)
    ap.add_argument("--gaussians", type=int, default=30000)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="504x378")
    ap.add_argument("--path", default="spiral")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from reings.backends import get_backend
    from reings.paths import camera_path
    from reings.video import _to_uint8, load_run

    w, h = (int(v) for v in a.size.split("x"))
    if a.run:
        g, recs = load_run(a.run)
        cams = [r.camera for r in recs]
    else:
        g, cams = synthetic(a.gaussians)
    op = 1 / (1 + np.exp(-g.opacity_logits.astype(np.float64)))
    path = camera_path(a.path, cams, a.frames, points=g.means, weights=op * (op > 0.1), size=(w, h))
    be = get_backend(a.device)
    for rgb, _ in be.render_frames(g, path[:1]):
        _to_uint8(rgb)
    t = time.perf_counter()
    n = 0
    for rgb, _ in be.render_frames(g, path):
        _to_uint8(rgb)
        n += 1
    secs = time.perf_counter() - t
    row = {"bench": "render_path", "device": getattr(be, "device_name", a.device), "gaussians": len(g),
           "sh_degree": g.sh_degree, "frames": n, "size": f"{w}x{h}", "path": a.path, "seconds": secs,
           "fps": n / secs, "model": a.run or "synthetic"}
    print(json.dumps(row))
    if a.json:
        with open(a.json, "a") as f:
            f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
