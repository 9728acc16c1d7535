import sys, time
src = sys.argv[1]; its = int(sys.argv[2])
sys.path.insert(0, src + '/bench'); sys.path.insert(0, src)
import bench_host, numpy as np
import reings
from bench_fit import surface_init
from reings.train import fit
from reings.backends.opencl.harness import launches_stubbed
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
def run(its, prof=None):
    cfg = bench_host.recipe(its, 1, 0.2, True)
    return fit(scene, cfg, device="pocl", init=init, depth_targets=list(scene.depths), log_every=10, engine="device", profile=prof)
run(3)
with launches_stubbed():
    run(its)
    prof = {}
    run(its, prof)
prof.pop("device_ms", None)
tot = sum(prof.values())
print(f"{src}: stubbed phases sum {tot/its*1e3:.3f} ms/it")
for k, v in sorted(prof.items(), key=lambda kv: -kv[1]):
    print(f"  {k:16s} {v/its*1e3:8.3f} ms/it")
