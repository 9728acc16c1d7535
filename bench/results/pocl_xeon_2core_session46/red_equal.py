"""isect_reduce on the real segment lengths vs the same K in equal segments (branch predictability)."""
import sys, time, numpy as np, pyopencl as cl
from ckscene import load
from reings.backends import get_backend
from reings.backends.opencl.rasterize import Rasterizer
defs = [dict(kv.split("=") for kv in s.split(",")) if s else {} for s in sys.argv[2:4]]
g, cam, proj, bins = load(sys.argv[1])
W, H = cam.width, cam.height
off = bins.offset_from_rank.astype(np.int32); V = len(bins.gid_from_rank); K = int(off[-1]); N = len(g)
L = np.diff(off); print("V", V, "K", K, "mean len", L.mean(), "p50/p90/p99/max", np.percentile(L, [50, 90, 99]), L.max())
uni = np.minimum(np.arange(V + 1) * K // V, K).astype(np.int32)
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
up = lambda x: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
rec = up(np.random.default_rng(0).normal(size=(K, 10)).astype(np.float32))
offs = {"real": up(off), "uniform": up(uni)}
gfr = up(bins.gid_from_rank.astype(np.int32))
out = cl.Buffer(ctx, mf.READ_WRITE, N * 40); cnt = cl.Buffer(ctx, mf.READ_WRITE, 16)
r = Rasterizer(be.handle)
for rep in range(3):
  for name in ("real", "uniform", "real", "uniform"):
    ts = []
    for it in range(25):
        q.finish(); t = time.perf_counter()
        r.reduce(rec, 10, offs[name], gfr, V, out); q.finish()
        ts.append(time.perf_counter() - t)
    print(name, "median ms %.3f" % (np.median(ts[5:]) * 1e3))
