"""device_time.py's profiled fit for a tree without depth orders (run from that tree's root:
    git archive be94a6d | tar -x -C /tmp/head; cd /tmp/head; python3 <this file> head head;
    be94a6d: the commit before this change, its backend as at f9137fb)
Each argument is a label of one 21-iteration profiled fit (it sets backend.depth_order, which the
old tree ignores); prints the device ms per iteration of a few stages."""
import os, sys, time
sys.path.insert(0, "bench")
import numpy as np
import reings
from bench_fit import surface_init
from bench_host import recipe
from reings.train import fit
from reings.backends import get_backend
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
be = get_backend("pocl")
def run(its, prof=None):
    return fit(scene, recipe(its, 1, 0.2, True), device="pocl", init=init, depth_targets=list(scene.depths), log_every=10, engine="device", profile=prof)
run(3)
for mode in sys.argv[1:]:
    be.depth_order = mode
    p = {}
    run(21, p)
    dm = p["device_ms"]
    tot = sum(dm.values())
    print(mode, os.getcwd(), f"device total {tot/21:.2f} ms/it", " ".join(f"{k} {dm.get(k, 0)/21:.3f}" for k in ("sort_depth", "bin_count", "project_fwd", "scan", "bin_emit", "isect_reduce")), flush=True)
