"""Device time per iteration of bench_host.py's case with the depth order shared and sorted, in one
process, alternating (a profiled fit: each stage's device time, summed / iterations).
    python3 bench/results/issue15_depth_order/device_time.py --device cuda --pairs 2 [--all]   (from the repo root)"""
import argparse, sys
import numpy as np
sys.path.insert(0, "bench")  # bench_fit, bench_host
import reings
from bench_fit import surface_init
from bench_host import recipe
from reings.backends import get_backend, set_queue_profiling
from reings.train import fit

ap = argparse.ArgumentParser()
ap.add_argument("--device", default="pocl")
ap.add_argument("--iterations", type=int, default=21)
ap.add_argument("--pairs", type=int, default=2)
ap.add_argument("--all", action="store_true", help="also print every stage's device time, largest first")
a = ap.parse_args()
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
set_queue_profiling(True)  # the stage times come from profiling events
be = get_backend(a.device)


def run(its, prof=None):
    return fit(scene, recipe(its, 1, 0.2, True), device=a.device, init=init, depth_targets=list(scene.depths),
               log_every=10, engine="device", profile=prof)


run(3)
print(f"{be.device_name}; {a.iterations} iterations per fit; ms per iteration (kernel sums of a profiled fit)")
for _ in range(a.pairs):
    for mode in ("sort", "share"):
        be.depth_order = mode
        before = dict(be.depth_sorts)
        prof = {}
        run(a.iterations, prof)
        dm, n = prof["device_ms"], a.iterations
        sorts = {k: (be.depth_sorts[k] - before[k]) / n for k in before}
        print(f"{mode:5s} device {sum(dm.values()) / n:8.3f}  sorts/it {sorts}  " +
              "  ".join(f"{k} {dm.get(k, 0.0) / n:.3f}" for k in ("sort_depth", "bin_count", "project_fwd", "bin_emit",
                                                                  "isect_reduce", "rasterize_fwd", "rasterize_bwd")),
              flush=True)
        if a.all:  # every stage, largest first
            print("      all: " + "  ".join(f"{k} {v / n:.3f}" for k, v in sorted(dm.items(), key=lambda kv: -kv[1])),
                  flush=True)
