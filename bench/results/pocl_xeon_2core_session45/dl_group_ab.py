"""dl_block_stats with DL_GROUP blocks per work-item, in one process (the groups' calls alternate; profiled, median
of 28 after 2): OPENBLAS_NUM_THREADS=1 python bench/results/pocl_xeon_2core_session45/dl_group_ab.py 1 8 16
(from the repository root; 504 x 378, patch sizes drawn from four pairs)."""
import sys, numpy as np
sys.path.insert(0, '.')
from reings.backends.opencl.losses import DepthLossCL
from reings.backends.opencl.device import open_device
h = open_device("pocl", profiling=True)
H, W = 378, 504
rng = np.random.default_rng(0)
d = (1 + rng.random((H, W))).astype(np.float32); t = (2 + rng.random((H, W))).astype(np.float32)
groups = [int(a) for a in sys.argv[1:]]
dls, times = {}, {}
for g in groups:
    dl = DepthLossCL(h, group=g); dl(d, t, 9, 13, 0.00025)
    orig = dl._call
    def call(name, *a, g=g, orig=orig):
        ev = orig(name, *a); times.setdefault((g, name), []).append(ev); return ev
    dl._call = call
    dls[g] = dl
for rep in range(30):
    for g in groups:
        pl, pg = [(5, 17), (9, 13), (17, 5), (11, 7)][rep % 4]
        dls[g](d, t, pl, pg, 0.00025)
h.queue.finish()
for g in groups:
    print(g, {n: round(float(np.median([(e.profile.end - e.profile.start) * 1e-6 for e in evs[2:]])), 3) for (gg, n), evs in times.items() if gg == g})
