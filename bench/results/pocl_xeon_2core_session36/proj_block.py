"""project_fwd / project_bwd: PROJ_BLOCK_IO 0 vs 1 alternating in one process; bytes compared."""
import sys, argparse, numpy as np
sys.path.insert(0, "bench"); sys.path.insert(0, ".")
from bench_rasterize import _scene
from reings.backends.opencl.device import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend
from reings.backends.base import RasterGrads
ap = argparse.ArgumentParser(); ap.add_argument("--checkpoint"); ap.add_argument("--runs", type=int, default=10)
ap.add_argument("--sh", type=int, default=None)
a = ap.parse_args()
ns = argparse.Namespace(checkpoint=a.checkpoint, n=None, opacity=None, cameras=None, view=0, scene=None)
g, cam = _scene(ns)
if a.sh is not None:
    from reings.types import SH_COUNTS
    k = SH_COUNTS[a.sh]
    g = g.__class__(**{**{f: getattr(g, f) for f in g.__dataclass_fields__}, "sh": np.ascontiguousarray(g.sh[:, :k])})
be = OpenCLBackend("pocl")

mode = {"v": 1}

print("N", len(g.means), "sh", g.sh.shape, "vw", be.proj_vw)
res = {0: {"fwd": [], "bwd": []}, 1: {"fwd": [], "bwd": []}}
outs = {}
n = len(g.means)
for r in range(a.runs + 2):
    rg = np.random.default_rng(r)
    gr = RasterGrads(v_means2d=rg.normal(size=(n, 2)).astype(np.float32), v_conics=rg.normal(size=(n, 3)).astype(np.float32),
                     v_colors=rg.normal(size=(n, 3)).astype(np.float32), v_opacities=rg.normal(size=n).astype(np.float32),
                     v_depths=rg.normal(size=n).astype(np.float32))
    for v in (0, 1):
        be.proj_block = bool(v)
        p = be.project_fwd(g, cam)
        pf = dict(be.last_profile)
        gg = be.project_bwd(g, cam, p, gr)
        pb = dict(be.last_profile)
        if r >= 2:
            res[v]["fwd"].append(pf.get("project_fwd", np.nan))
            res[v]["bwd"].append(pb.get("project_bwd", np.nan))
        outs[v] = (p, gg)
    (p0, g0), (p1, g1) = outs[0], outs[1]
    bad = []
    for f in ("means2d", "conics", "colors", "opacities", "depths", "radii", "tile_rect", "packed"):
        if not hasattr(p0, f): continue
        x, y = np.asarray(getattr(p0, f)), np.asarray(getattr(p1, f))
        if not np.array_equal(x.view(np.uint8), y.view(np.uint8)): bad.append(f)
    for f in g0.__dataclass_fields__ if hasattr(g0, "__dataclass_fields__") else g0:
        x = np.asarray(getattr(g0, f) if hasattr(g0, f) else g0[f]); y = np.asarray(getattr(g1, f) if hasattr(g1, f) else g1[f])
        if not np.array_equal(x.view(np.uint8), y.view(np.uint8)): bad.append("v_" + f)
    if bad: print("run", r, "DIFFER", bad)
for v in res:
    print("PROJ_BLOCK_IO", v, "fwd median ms %.3f" % np.median(res[v]["fwd"]), "bwd median ms %.3f" % np.median(res[v]["bwd"]))
print("ratio fwd %.3f bwd %.3f" % (np.median(np.array(res[1]["fwd"]) / res[0]["fwd"]), np.median(np.array(res[1]["bwd"]) / res[0]["bwd"])))
