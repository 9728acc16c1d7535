import sys, cProfile, pstats, io, time
src = sys.argv[1]; its = int(sys.argv[2]); out = sys.argv[3] if len(sys.argv) > 3 else None
sys.path.insert(0, src + '/bench'); sys.path.insert(0, src)
import bench_host, numpy as np
import reings
from bench_fit import surface_init
from reings.train import fit
from reings.backends.opencl.harness import launches_stubbed
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
def run(its):
    cfg = bench_host.recipe(its, 1, 0.2, True)
    return fit(scene, cfg, device="pocl", init=init, depth_targets=list(scene.depths), log_every=10, engine="device")
run(3)
with launches_stubbed():
    run(its)
    p = cProfile.Profile(); p.enable(); run(its); p.disable()
s = io.StringIO()
st = pstats.Stats(p, stream=s); st.sort_stats('tottime').print_stats(30); st.sort_stats('cumulative').print_stats(40)
txt = f"# cProfile, {its}-iteration fit with every kernel launch stubbed ({src}); per-iteration = /{its}\n" + s.getvalue()
print(txt)
if out: open(out, 'w').write(txt)
