"""view_warp_bwd_depth with VW_CHUNK pixels per work-item against one: builds alternating, outputs byte-compared.
Not kept, and the kernel form (the per-pixel body in a loop over VW_CHUNK pixels of a row, a grid of ceil(W / VW_CHUNK)
columns) is not in kernels/view_warp.cl: without it the chunked launches cover part of each row and the check fails."""
import sys, time, numpy as np, pyopencl as cl
from reings.backends import get_backend
from reings.backends.opencl.program import library_for
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
H, W = 378, 504
chunks = [int(x) for x in sys.argv[1:]] or [1, 16]
rng = np.random.default_rng(0)
depth = (rng.random((H, W)) * 3 + 0.5).astype(np.float32); depth[5, 7] = np.nan; depth[9, 9] = -1e-5
virt = rng.random((H, W, 3)).astype(np.float32); gt = rng.random((H, W, 3)).astype(np.float32)
sxy = rng.normal(size=(H, W, 2)).astype(np.float32)
up = lambda x: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
bv, bd, bg, bs = up(virt), up(depth), up(gt), up(sxy)
ks, outs = [], []
for c in chunks:
    prg = library_for(be.handle).program("view_warp.cl", VW_WG=1, REINGS_CPU_SCHEDULE=1, VW_CHUNK=c)
    k = cl.Kernel(prg, "view_warp_bwd_depth"); ks.append(k)
    outs.append([cl.Buffer(ctx, mf.READ_WRITE, H * W * n * 4) for n in (1, 1, 6, 2)])
nfb, gl, gs = np.float32(-0.3 * 400), np.float32(1.0 / (3 * H * W)), np.float32(0.1 / ((H - 2) * (W - 2)))
res = [[] for _ in chunks]
pad = lambda n, l: -(-n // l) * l
for it in range(40):
    for j in (range(len(chunks)) if it % 2 else reversed(range(len(chunks)))):
        for b in outs[j]: cl.enqueue_fill_buffer(q, b, np.float32(0), 0, b.size)
        q.finish(); t = time.perf_counter()
        ks[j](q, (pad(-(-W // chunks[j]), 64), H), (64, 1), bv, bd, bg, bs, *outs[j], nfb, gl, gs, np.int32(0), np.int32(W), np.int32(H))
        q.finish(); res[j].append(time.perf_counter() - t)
o = []
for j in range(len(chunks)):
    xs = [np.empty(b.size // 4, np.uint32) for b in outs[j]]
    for b, x in zip(outs[j], xs): cl.enqueue_copy(q, x, b)
    o.append(xs)
for j in range(1, len(chunks)): assert all(np.array_equal(a, b) for a, b in zip(o[0], o[j]))
print("chunks", chunks, "ms", ["%.3f" % (np.median(x[4:]) * 1e3) for x in res], "ratios", ["%.3f" % np.median(np.array(res[j][4:]) / np.array(res[0][4:])) for j in range(len(chunks))])
