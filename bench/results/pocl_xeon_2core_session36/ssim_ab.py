import sys, time, numpy as np
sys.path.insert(0, ".")
import reings.backends.opencl.rasterize as R
from reings.backends.opencl.losses import PhotometricCL
orig = R.native_lanes
objs = {}
for vw in (8, 16):
    R.native_lanes = lambda d, vw=vw: vw
    objs[vw] = PhotometricCL("pocl")
R.native_lanes = orig
rng = np.random.default_rng(0)
h, w = 378, 504
x = rng.uniform(0, 1, (h, w, 3)).astype(np.float32); y = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
outs = {}
for vw, p in objs.items():
    outs[vw] = p(x, y, 0.8, 0.2)
assert outs[8][0] == outs[16][0] and np.array_equal(outs[8][1].view(np.uint32), outs[16][1].view(np.uint32)), "bits differ"
print("same bits")
t = {8: [], 16: []}
for r in range(40):
    for vw, p in objs.items():
        p.enqueue(p.x, p.y, p.v, h, w, 0.8, 0.2, value=False)
        p.handle.queue.finish()
        t0 = time.perf_counter()
        for _ in range(3): p.enqueue(p.x, p.y, p.v, h, w, 0.8, 0.2, value=False)
        p.handle.queue.finish()
        t[vw].append((time.perf_counter() - t0) / 3 * 1e3)
for vw in t: print(vw, "median ms %.3f" % np.median(t[vw]))
print("ratio %.3f" % np.median(np.array(t[16]) / np.array(t[8])))
