"""The device time per iteration of bench_host.py's case (a profiled fit: sum of the stage times / iterations).
    REINGS_BIN=async python3 bench/results/issue15_sync_free_binning/device_time.py   (run from the repository root)"""
import os, sys, numpy as np
sys.path.insert(0, "bench")  # bench_fit, bench_host
import reings
from bench_fit import surface_init
from bench_host import recipe
from reings.train import fit
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
for its in (3, 101):
    prof = {}
    r = fit(scene, recipe(its, 1, 0.2, True), device="cuda", init=init, depth_targets=list(scene.depths),
            log_every=10, engine="device", profile=prof)
dm = prof.get("device_ms", {})
tot = sum(dm.values())
print(f"device ms/iteration (kernel sums, profiled run): {tot / 101:.3f}")
for k, v in sorted(dm.items(), key=lambda kv: -kv[1])[:12]:
    print(f"  {k:24s} {v / 101:.3f}")
