import sys, numpy as np
sys.path.insert(0, "."); sys.path.insert(0, "tests")
from reings.backends.opencl.device import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.view_warp import ViewWarpCL
import pyopencl as cl
rng = np.random.default_rng(0)
h, w, fx, b = 378, 504, 407.0, 0.4
y, x = np.mgrid[0:h, 0:w]
depth = (20.0 + 40.0 * x / w + 3.0 * np.sin(y / 17.0)).astype(np.float32)
depth[100:250, 150:300] = 8.0
virt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32); gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
vw = ViewWarpCL("pocl")
ctx, q = vw.handle.context, vw.handle.queue
mf = cl.mem_flags
B = {k: cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for k, a in (("virt", virt), ("depth", depth), ("gt", gt))}
ov = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12); od = cl.Buffer(ctx, mf.READ_WRITE, h * w * 4)
edges = cl.Buffer(ctx, mf.READ_WRITE, h * w * 8)
t = {}
for r in range(25):
    if hasattr(vw, "edges"):
        vw.edges(B["gt"], h, w, out=edges); q.finish()
        ev = vw.events[0][1]; t.setdefault("edges", []).append((ev.profile.end - ev.profile.start) * 1e-6)
        vw.enqueue(B["virt"], B["depth"], B["gt"], ov, od, h, w, fx, b, edges=edges)
    else:
        vw.enqueue(B["virt"], B["depth"], B["gt"], ov, od, h, w, fx, b)
    q.finish()
    for name, ev in vw.events:
        t.setdefault(name, []).append((ev.profile.end - ev.profile.start) * 1e-6)
for k, v in t.items(): print(k, "median ms %.3f" % np.median(v[5:]))
