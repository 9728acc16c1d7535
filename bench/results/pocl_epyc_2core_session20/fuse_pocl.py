# python bench/results/pocl_epyc_2core_session20/fuse_pocl.py   (from the repo root; output: fuse_pocl.txt)
# PoCL, 2 cores: bench_host's case (504x378, 30k Gaussians, SH 1, every pass of a late fine iteration) with the
# soft depth term shared (the paper preset's LLFF default), the fused soft backward on / off, alternating.
import sys, time
from dataclasses import replace
import numpy as np
sys.path.insert(0, "bench")
import reings
from bench_fit import surface_init
from bench_host import recipe
from reings.train import fit
from reings.backends.opencl.trainer import DeviceTrainer
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
def cfg(its):
    c = recipe(its, 1, 0.2, True)
    return replace(c, loss=replace(c.loss, hard_depth=False, soft_depth_shared=True))
def run(its):
    return fit(scene, cfg(its), device="pocl", init=init, depth_targets=list(scene.depths), log_every=10, engine="device")
run(3)
out = {}
for rep in range(2):
    for fuse in (False, True):
        DeviceTrainer.fuse_soft_backward = fuse
        r = run(21)
        h = r.history
        ms = (h.seconds[-1] - h.seconds[0]) / (h.iteration[-1] - h.iteration[0]) * 1e3
        out.setdefault(fuse, []).append(ms)
        print(f"fuse={fuse} {ms:.1f} ms/iteration loss {h.loss[-1]:.6f}", flush=True)
print({k: [round(v, 1) for v in vs] for k, vs in out.items()})
