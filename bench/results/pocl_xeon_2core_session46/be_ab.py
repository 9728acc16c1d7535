"""bin_emit with BE_CHUNK ranks per work-item against one (session 46, not kept). Needs the kernel form of
be_chunk.patch (`git apply bench/results/pocl_xeon_2core_session46/be_chunk.patch`, applies on dba606a): without it
the chunked launches cover only part of the ranks and the byte check fails. Usage: python be_ab.py CK/fine.npz 1 8 32"""
import sys, time, numpy as np, pyopencl as cl
from ckscene import load
from reings.backends import get_backend
from reings.backends.base import tile_grid
chunks = [int(x) for x in sys.argv[2:]]
g, cam, proj, bins = load(sys.argv[1])
W, H = cam.width, cam.height
tx, ty = tile_grid(W, H)
V = len(bins.gid_from_rank); K = int(bins.offset_from_rank[-1])
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
up = lambda x: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
gfr, off, rect = up(bins.gid_from_rank.astype(np.uint32)), up(bins.offset_from_rank.astype(np.uint32)), up(proj.tile_rect.astype(np.int32))
outs = [[cl.Buffer(ctx, mf.READ_WRITE, K * 4) for _ in range(3)] for _ in chunks]
cnt = cl.Buffer(ctx, mf.READ_WRITE, 16)
ks = [be.kernel("bin.cl", "bin_emit", BE_CHUNK=c) for c in chunks]
res = [[] for _ in chunks]
for it in range(40):
    for j in (range(len(chunks)) if it % 2 else reversed(range(len(chunks)))):
        q.finish(); t = time.perf_counter()
        be.launch(ks[j], -(-V // chunks[j]), np.int32(V), np.int32(tx), gfr, off, rect, *outs[j], cnt, np.int32(-1))
        q.finish(); res[j].append(time.perf_counter() - t)
got = []
for j in range(len(chunks)):
    o = [np.empty(K, np.uint32) for _ in range(3)]
    for b, x in zip(outs[j], o): cl.enqueue_copy(q, x, b)
    got.append(o)
for j in range(1, len(chunks)):
    assert all(np.array_equal(x, y) for x, y in zip(got[0], got[j]))
assert np.array_equal(got[0][2][bins.emit_from_isect], bins.gid_from_isect)
print("K", K, "chunks", chunks, "ms", ["%.3f" % (np.median(x[4:]) * 1e3) for x in res], "ratios", ["%.3f" % np.median(np.array(res[j][4:]) / np.array(res[0][4:])) for j in range(len(chunks))])
