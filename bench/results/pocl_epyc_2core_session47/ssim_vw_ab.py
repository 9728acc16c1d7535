"""The four CPU SSIM passes with SSIM_VW 8 against 16 (builds alternating; every output byte-compared)."""
import sys, time, numpy as np, pyopencl as cl
from reings.backends import get_backend
from reings.backends.opencl.program import library_for
from reings.backends.opencl.losses import SSIM_ROWS
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
H, W = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (378, 504)
rng = np.random.default_rng(0)
x = rng.random((H, W, 3)).astype(np.float32); y = rng.random((H, W, 3)).astype(np.float32)
g = np.exp(-0.5 * (np.arange(-5, 6) / 1.5) ** 2); taps = (g / g.sum()).astype(np.float32)
up = lambda a: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))
bx, by, bt = up(x), up(y), up(taps)
n = H * W * 3
names = ("ssim_hpass_fwd", "ssim_vpass_fwd", "ssim_hpass_bwd", "ssim_vpass_bwd")
builds = []
for v in (8, 16):
    prg = library_for(be.handle).program("photometric.cl", SSIM_ROWS=SSIM_ROWS, SSIM_VW=v)
    ks = {nm: cl.Kernel(prg, nm) for nm in names}
    bufs = {"h5": cl.Buffer(ctx, mf.READ_WRITE, 5 * n * 4), "smap": cl.Buffer(ctx, mf.READ_WRITE, n * 4),
            "d3": cl.Buffer(ctx, mf.READ_WRITE, 3 * n * 4), "h3": cl.Buffer(ctx, mf.READ_WRITE, 3 * n * 4),
            "vx": cl.Buffer(ctx, mf.READ_WRITE, n * 4)}
    builds.append((ks, bufs))
gs = (-(-H // SSIM_ROWS),)
I, F = np.int32, np.float32
def run(ks, b):
    ts = []
    for nm, args in (("ssim_hpass_fwd", (bx, by, bt, b["h5"], I(W), I(H))),
                     ("ssim_vpass_fwd", (b["h5"], bt, b["smap"], b["d3"], F(-0.2 / n), I(W), I(H))),
                     ("ssim_hpass_bwd", (b["d3"], bt, b["h3"], I(W), I(H))),
                     ("ssim_vpass_bwd", (b["h3"], bx, by, bt, b["vx"], F(0.8 / n), I(W), I(H)))):
        q.finish(); t = time.perf_counter(); ks[nm](q, gs, None, *args); q.finish(); ts.append(time.perf_counter() - t)
    return ts
res = [[], []]
for it in range(30):
    for j in ((0, 1) if it % 2 else (1, 0)):
        res[j].append(run(*builds[j]))
for key, size in (("h5", 5 * n), ("smap", n), ("d3", 3 * n), ("h3", 3 * n), ("vx", n)):
    o = [np.empty(size, np.uint32) for _ in range(2)]
    for j in range(2): cl.enqueue_copy(q, o[j], builds[j][1][key])
    assert np.array_equal(o[0], o[1]), key
a, b = np.array(res[0][4:]), np.array(res[1][4:])
print(f"{H}x{W}", "ms VW=8", np.round(np.median(a, 0) * 1e3, 3), "VW=16", np.round(np.median(b, 0) * 1e3, 3),
      "ratios", np.round(np.median(b / a, 0), 3), "sum ratio %.3f" % np.median(b.sum(1) / a.sum(1)))
