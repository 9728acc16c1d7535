"""isect_reduce at REDUCE_CHUNK ranks per work-item, the builds alternating, outputs byte-compared. Usage:
python red_ab.py CK/STAGE.npz 1 16 [...]. Since dba606a REDUCE_CHUNK=1 is the vector-fields form at one rank per
work-item; the scalar per-rank form that ab_console.txt's 0.46-0.50 ratios compare against is the CPU isect_reduce
of 22b7d83 (a tree checked out there, chunk 1 against 16)."""
import sys, time, numpy as np, pyopencl as cl
from ckscene import load
from reings.backends import get_backend
from reings.backends.opencl.rasterize import Rasterizer
chunks = [int(x) for x in sys.argv[2:]]
g, cam, proj, bins = load(sys.argv[1])
W, H = cam.width, cam.height
off = bins.offset_from_rank.astype(np.int32); V = len(bins.gid_from_rank); K = int(off[-1]); N = len(g)
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
up = lambda x: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
recs = np.random.default_rng(0).normal(size=(K, 10)).astype(np.float32)
recs[5, 3] = np.inf; recs[6, 3] = -np.inf; recs[100, 9] = 3e38; recs[101, 9] = 3e38  # overflow cases
rec = up(recs); offb = up(off); gfr = up(bins.gid_from_rank.astype(np.int32))
outs = [cl.Buffer(ctx, mf.READ_WRITE, N * 40) for _ in chunks]
rs = [Rasterizer(be.handle, REDUCE_CHUNK=c) for c in chunks]
res = [[] for _ in chunks]
for it in range(40):
    order = range(len(chunks)) if it % 2 else reversed(range(len(chunks)))
    for j in order:
        cl.enqueue_fill_buffer(q, outs[j], np.float32(0.5), 0, N * 40); q.finish(); t = time.perf_counter()
        rs[j].reduce(rec, 10, offb, gfr, V, outs[j], accumulate=bool(it % 3 == 0)); q.finish()
        res[j].append(time.perf_counter() - t)
    o = [np.empty(N * 10, np.float32) for _ in chunks]
    for j in range(len(chunks)): cl.enqueue_copy(q, o[j], outs[j])
    for j in range(1, len(chunks)): assert np.array_equal(o[0].view(np.uint32), o[j].view(np.uint32)), (it, j)
m = [np.median(x[4:]) * 1e3 for x in res]
print("chunks", chunks, "ms", ["%.3f" % x for x in m], "ratios", ["%.3f" % (np.median(np.array(res[j][4:]) / np.array(res[0][4:]))) for j in range(len(chunks))])
