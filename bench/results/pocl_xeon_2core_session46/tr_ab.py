"""In-process A/B of tile_ranges (TR_PREFETCH, tried in session 46, is no longer in kernels/bin.cl; TR_CHUNK is): builds with -D defines alternating, on a checkpoint's binning."""
import sys, time, numpy as np, pyopencl as cl
from ckscene import load
from reings.backends import get_backend
defs = [dict(kv.split("=") for kv in s.split(",")) if s else {} for s in sys.argv[2:4]]
g, cam, proj, bins = load(sys.argv[1])
W, H = cam.width, cam.height
K = len(bins.gid_from_isect); T = len(bins.tile_ranges)
tile_of = np.repeat(np.arange(T), bins.tile_ranges[:, 1] - bins.tile_ranges[:, 0]).astype(np.uint32)
gid_from_emit = np.repeat(bins.gid_from_rank, np.diff(bins.offset_from_rank)).astype(np.uint32)
assert np.array_equal(gid_from_emit[bins.emit_from_isect], bins.gid_from_isect)
be = get_backend("pocl")
ctx, q = be.handle.context, be.queue
mf = cl.mem_flags
up = lambda x: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(x))
bk, be_, bg = up(tile_of), up(bins.emit_from_isect.astype(np.uint32)), up(gid_from_emit)
ranges = cl.Buffer(ctx, mf.READ_WRITE, T * 8); gfi = cl.Buffer(ctx, mf.READ_WRITE, K * 4)
cnt = cl.Buffer(ctx, mf.READ_WRITE, 16)
ks = [be.kernel("bin.cl", "tile_ranges", **{a: b for a, b in d.items() if a != "WG"}) for d in defs]
res = [[], []]
for rep in range(40):
    for j in ((0, 1) if rep % 2 else (1, 0)):
        q.finish(); t = time.perf_counter()
        be.launch(ks[j], -(-(K + 1) // int(defs[j].get('TR_CHUNK', 1))), wg=int(defs[j].get('WG', 256)), *( np.int32(K), np.int32(T), bk, be_, bg, ranges, gfi, cnt, np.int32(-1)))
        q.finish(); res[j].append(time.perf_counter() - t)
        out = np.empty(K, np.int32); cl.enqueue_copy(q, out, gfi); r2 = np.empty((T, 2), np.int32); cl.enqueue_copy(q, r2, ranges)
        assert np.array_equal(out, bins.gid_from_isect) and np.array_equal(r2, bins.tile_ranges)
a0, a1 = np.array(res[0][5:]), np.array(res[1][5:])
print("K", K, "A ms %.3f B ms %.3f ratio B/A %.3f" % (np.median(a0) * 1e3, np.median(a1) * 1e3, np.median(a1) / np.median(a0)))
