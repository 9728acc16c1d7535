"""Byte check of a CPU-schedule define: rasterize_bwd's records and reduced gradients with DEFINE=0 and DEFINE=1 on
reings checkpoints, seen from view 1 of their run: the photometric backward (an image cotangent), the hard pass
(every opacity 0.99, a depth cotangent) and a depth cotangent at the real opacities.

    python bits_ab.py RASTER_HITS RUN/checkpoints/coarse.npz RUN/checkpoints/fine.npz ..."""
import sys, argparse
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))
import bench_rasterize as B
from reings.backends import reference as ref
from reings.backends.opencl.rasterize import rasterize_bwd_host
DEFINE = sys.argv[1]
for ck in sys.argv[2:]:
    for opac, cot in ((None, "rgb"), (0.99, "depth"), (None, "depth")):
        a = argparse.Namespace(checkpoint=ck, opacity=opac, cameras=None, view=1, scene=None, n=None)
        g, cam = B._scene(a)
        W, H = cam.width, cam.height
        proj = ref.project_fwd(g, cam); bins = ref.bin(proj, W, H)
        rng = np.random.default_rng(0)
        kw = {"v_rgb": rng.normal(size=(H, W, 3)).astype(np.float32)} if cot == "rgb" else {"v_depth": rng.normal(size=(H, W)).astype(np.float32)}
        outs = []
        for hits in ("0", "1"):
            o = rasterize_bwd_host(proj, bins, W, H, device="pocl", **{DEFINE: hits}, **kw)
            outs.append(o)
        same = all(np.array_equal(getattr(outs[0], f).view(np.uint32), getattr(outs[1], f).view(np.uint32)) for f in ("v_emit", "v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"))
        print(ck.split("/")[-1], opac, cot, "K", len(bins.gid_from_isect), "same bytes:", same, flush=True)
