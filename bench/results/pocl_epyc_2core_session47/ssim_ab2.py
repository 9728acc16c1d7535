"""The four CPU SSIM passes at two builds given as define lists, e.g. "SSIM_VW=8" "SSIM_VW=16,SSIM_ROWS=8" (the builds
alternating in one process; every output byte-compared). argv: A B [reps [H W]] (default 40 repetitions at 378 x 504).
SSIM_ROWS defaults to losses.SSIM_ROWS, SSIM_VW to 8."""
import sys, time, numpy as np, pyopencl as cl
from reings.backends import get_backend
from reings.backends.opencl.program import library_for
from reings.backends.opencl.losses import SSIM_ROWS
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
H, W = (int(sys.argv[4]), int(sys.argv[5])) if len(sys.argv) > 5 else (378, 504)
rng = np.random.default_rng(0)
x = rng.random((H, W, 3)).astype(np.float32); y = rng.random((H, W, 3)).astype(np.float32)
g = np.exp(-0.5 * (np.arange(-5, 6) / 1.5) ** 2); taps = (g / g.sum()).astype(np.float32)
up = lambda a: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))
bx, by, bt = up(x), up(y), up(taps)
n = H * W * 3
names = ("ssim_hpass_fwd", "ssim_vpass_fwd", "ssim_hpass_bwd", "ssim_vpass_bwd")
builds = []
for spec in sys.argv[1:3]:
    d = {"SSIM_ROWS": SSIM_ROWS, "SSIM_VW": 8}
    d.update({k: int(v) for k, v in (kv.split("=") for kv in spec.split(","))})
    prg = library_for(be.handle).program("photometric.cl", **d)
    ks = {nm: cl.Kernel(prg, nm) for nm in names}
    bufs = {"h5": cl.Buffer(ctx, mf.READ_WRITE, 5 * n * 4), "smap": cl.Buffer(ctx, mf.READ_WRITE, n * 4),
            "d3": cl.Buffer(ctx, mf.READ_WRITE, 3 * n * 4), "h3": cl.Buffer(ctx, mf.READ_WRITE, 3 * n * 4),
            "vx": cl.Buffer(ctx, mf.READ_WRITE, n * 4)}
    builds.append((ks, bufs, (-(-H // d["SSIM_ROWS"]),)))
I, F = np.int32, np.float32
def run(ks, b, gs):
    ts = []
    for nm, args in (("ssim_hpass_fwd", (bx, by, bt, b["h5"], I(W), I(H))),
                     ("ssim_vpass_fwd", (b["h5"], bt, b["smap"], b["d3"], F(-0.2 / n), I(W), I(H))),
                     ("ssim_hpass_bwd", (b["d3"], bt, b["h3"], I(W), I(H))),
                     ("ssim_vpass_bwd", (b["h3"], bx, by, bt, b["vx"], F(0.8 / n), I(W), I(H)))):
        q.finish(); t = time.perf_counter(); ks[nm](q, gs, None, *args); q.finish(); ts.append(time.perf_counter() - t)
    return ts
res = [[], []]
for it in range(int(sys.argv[3]) if len(sys.argv) > 3 else 40):
    for j in ((0, 1) if it % 2 else (1, 0)):
        res[j].append(run(*builds[j]))
for key, size in (("h5", 5 * n), ("smap", n), ("d3", 3 * n), ("h3", 3 * n), ("vx", n)):
    o = [np.empty(size, np.uint32) for _ in range(2)]
    for j in range(2): cl.enqueue_copy(q, o[j], builds[j][1][key])
    assert np.array_equal(o[0], o[1]), key
a, b = np.array(res[0][4:]), np.array(res[1][4:])
print(f"{H}x{W} A {sys.argv[1]} ms", np.round(np.median(a, 0) * 1e3, 3), f"B {sys.argv[2]} ms", np.round(np.median(b, 0) * 1e3, 3),
      "B/A per pass", np.round(np.median(b / a, 0), 3), "all four B/A %.3f (q25 %.3f q75 %.3f)" % (
          np.median(b.sum(1) / a.sum(1)), *np.quantile(b.sum(1) / a.sum(1), [.25, .75])))
