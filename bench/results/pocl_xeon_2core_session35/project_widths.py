"""project_fwd / project_bwd on a reings checkpoint: PROJ_VW a vs b alternating in one process (device time from profiling events; run from the repository root).

    python bench/results/pocl_xeon_2core_session35/project_widths.py --checkpoint RUN/checkpoints/fine.npz --runs 25 --a 16 --b 8
"""
import sys, argparse, numpy as np
sys.path.insert(0, "bench"); sys.path.insert(0, ".")
from bench_rasterize import _scene
from reings.backends.opencl.device import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend
ap = argparse.ArgumentParser(); ap.add_argument("--checkpoint"); ap.add_argument("--runs", type=int, default=10)
ap.add_argument("--a", type=int, default=8); ap.add_argument("--b", type=int, default=16)
a = ap.parse_args()
ns = argparse.Namespace(checkpoint=a.checkpoint, n=None, opacity=None, cameras=None, view=0, scene=None)
g, cam = _scene(ns)
be = OpenCLBackend("pocl")
print("N", len(g.means), "sh", g.sh.shape)
rng = np.random.default_rng(0)
res = {a.a: {"fwd": [], "bwd": []}, a.b: {"fwd": [], "bwd": []}}
outs = {}
for r in range(a.runs + 2):
    for vw in (a.a, a.b):
        be.proj_vw = vw; be.proj_wg = 64 * 8 // vw
        p = be.project_fwd(g, cam)
        pf = dict(be.last_profile)
        from reings.backends.base import RasterGrads
        n = len(g.means); rg = np.random.default_rng(r)
        gr = RasterGrads(v_means2d=rg.normal(size=(n, 2)).astype(np.float32), v_conics=rg.normal(size=(n, 3)).astype(np.float32),
                         v_colors=rg.normal(size=(n, 3)).astype(np.float32), v_opacities=rg.normal(size=n).astype(np.float32),
                         v_depths=rg.normal(size=n).astype(np.float32))
        be.project_bwd(g, cam, None, gr)
        pb = dict(be.last_profile)
        if r >= 2:
            res[vw]["fwd"].append(pf.get("project_fwd", np.nan))
            res[vw]["bwd"].append(pb.get("project_bwd", np.nan))
        outs[vw] = p
for vw in res:
    print(vw, "fwd median ms", np.median(res[vw]["fwd"]), "bwd median ms", np.median(res[vw]["bwd"]))
pa, pb = outs[a.a], outs[a.b]
for f in ("means2d", "conics", "colors", "opacities", "depths", "radii"):
    x, y = np.asarray(getattr(pa, f)), np.asarray(getattr(pb, f))
    print(f, "identical bytes" if np.array_equal(x.view(np.uint8), y.view(np.uint8)) else f"DIFFER max {np.abs(x.astype(np.float64)-y).max()}")
