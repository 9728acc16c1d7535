"""In one process, alternating: the device trainer's step_l1 on PoCL with adam_multi True / False (54k Gaussians,
SH degree 1, scene A's layout); wall per step and Adam's device ms (profiling events)."""
import sys, time, numpy as np
sys.path.insert(0, "/work/main")
from reings.backends import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend
from reings.bench import make_step_trainer, step_target
from reings.bench_scenes import perf_scene
n = int(sys.argv[1]) if len(sys.argv) > 1 else 54_000
g, cam = perf_scene("A", n=n, sh_degree=1)
be = OpenCLBackend("pocl")
t, opt = make_step_trainer(be, g, step_target(cam))
for _ in range(3):
    t.step_l1(cam, 0, opt)
be.queue.finish()
wall = {True: [], False: []}; adam = {True: [], False: []}
for it in range(24):
    m = (it % 4) in (0, 3)
    t.adam_multi = m
    prof = {}; t.profile = prof
    t.finish(); t0 = time.perf_counter()
    t.step_l1(cam, 0, opt); t.finish()
    wall[m].append(1e3 * (time.perf_counter() - t0))
    t.profile = None
    adam[m].append(prof.get("device_ms", {}).get("adam", np.nan))
for m in (True, False):
    print("multi" if m else "per-group", "wall ms median", round(np.median(wall[m]), 2), "adam dev ms", round(np.nanmedian(adam[m]), 2))
print("wall ratio per-group/multi", round(np.median(wall[False]) / np.median(wall[True]), 3))
