"""Session 38: the coarse fit's hard depth pass (opacity 0.99, a depth cotangent) at full and at 1/2 resolution
(`train.depth_pass_camera`), rasterize_prep + rasterize_fwd + rasterize_bwd + isect_reduce, the two sizes alternating
run by run in one process (A, B, B, A, ...), device-time medians and the median per-run ratio.

    python bench/results/pocl_xeon_2core_session38/hard_scale_ab.py CK/coarse.npz [--runs 12]
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", ".."))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

from bench_rasterize import _ms, _scene, _upload  # noqa: E402
from reings.backends import reference as ref  # noqa: E402
from reings.backends.base import V_RECORD  # noqa: E402
from reings.train import depth_pass_camera  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("checkpoint")
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--view", type=int, default=0)
    a = ap.parse_args()
    import pyopencl as cl

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.rasterize import Rasterizer

    args = argparse.Namespace(checkpoint=a.checkpoint, n=None, opacity=0.99, cameras=None, view=a.view, scene=None)
    g, cam = _scene(args)
    h = open_device("pocl", profiling=True)
    sides = []
    for c in (cam, depth_pass_camera(cam, 2)):
        proj = ref.project_fwd(g, c)
        bins = ref.bin(proj, c.width, c.height)
        b = _upload(h, proj, bins, c.width, c.height)
        grads = cl.Buffer(h.context, cl.mem_flags.READ_WRITE, max(len(g), 1) * V_RECORD * 4)
        sides.append((c, bins, b, grads, Rasterizer(h), len(bins.gid_from_isect), len(bins.gid_from_rank)))
    times = [[], []]
    for it in range(a.warmup + a.runs):
        for j in ((0, 1) if it % 2 == 0 else (1, 0)):
            c, bins, b, grads, r, k, v = sides[j]
            W, H, n = c.width, c.height, len(g)
            e0 = r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
            e1 = r.fwd(None, None, None, None, None, n, b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"],
                       k, W, H, (0, 0, 0), prepared=True)
            e2 = r.bwd(b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], k, W, H, v_depth=b["v_depth"])
            e3 = r.reduce(r.v_emit, V_RECORD, b["offset_from_rank"], b["gid_from_rank"], v, grads)
            h.queue.finish()
            if it >= a.warmup:
                times[j].append([_ms(e) for e in (e0, e1, e2, e3)])
    t = [np.array(x) for x in times]
    tot = [x.sum(1) for x in t]
    print(json.dumps(dict(checkpoint=a.checkpoint, sizes=[[s[0].width, s[0].height] for s in sides],
                          intersections=[s[5] for s in sides],
                          full_ms=[round(float(np.median(t[0][:, i])), 3) for i in range(4)],
                          half_ms=[round(float(np.median(t[1][:, i])), 3) for i in range(4)],
                          total_ratio_median=round(float(np.median(tot[1] / tot[0])), 4),
                          total_ratio_q25_q75=[round(float(q), 4) for q in np.percentile(tot[1] / tot[0], [25, 75])])))


if __name__ == "__main__":
    main()
