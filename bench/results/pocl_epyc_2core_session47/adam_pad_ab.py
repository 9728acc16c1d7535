"""adam_step (the strided SH groups' kernel) on CPU with its columns padded to 16 lanes (trainer's choice) against
padded to PAD (argv[1], e.g. 4 or 8), and adam_step_flat on the same element count for scale; N Gaussians (argv[2]),
SH degree 1 views: sh_dc (cols 3, g_off 0) and sh_rest (cols 9, g_off 3) of a [N, 12] gradient. The two paddings
alternate; p / m / v compared byte for byte after the same steps."""
import sys, time, numpy as np, pyopencl as cl
from reings.backends import get_backend
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
PAD, N = int(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 50000
k = be.kernel("adam.cl", "adam_step", ADAM_FP64=1, ADAM_MULTI_SPLIT=1, ADAM_LOADS_FIRST=0)
kf = be.kernel("adam.cl", "adam_step_flat", ADAM_FP64=1, ADAM_MULTI_SPLIT=1, ADAM_LOADS_FIRST=0)
rng = np.random.default_rng(0)
g = rng.normal(size=(N, 12)).astype(np.float32)
bg = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=g)
U, F, D = np.uint32, np.float32, np.float64
sc = (F(0.9), F(0.1), F(0.999), F(0.001), D(1 / np.sqrt(1 - 0.999 ** 5)), F(1e-15), F(-1e-3))
def bufs(cols):
    return [cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.full(N * cols, 0.5 if j == 0 else 0.01, np.float32))
            for j in range(3)]
state = {pad: {c: bufs(c) for c in (3, 9)} for pad in (16, PAD)}
flat = {c: bufs(c) for c in (3, 9)}
gflat = {c: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(g[:, :c])) for c in (3, 9)}
def step(pad, cols, off):
    cpad = -(-cols // pad) * pad
    ly = max(1, 64 // cpad)
    q.finish(); t = time.perf_counter()
    k(q, (cpad, -(-N // ly) * ly), (cpad, ly), U(N), U(cols), *state[pad][cols], bg, U(12), U(off), U(cols), *sc)
    q.finish(); return time.perf_counter() - t
def stepf(cols):
    q.finish(); t = time.perf_counter()
    kf(q, (-(-N * cols // 256) * 256,), (256,), U(N * cols), *flat[cols], gflat[cols], *sc)
    q.finish(); return time.perf_counter() - t
t = {}
for it in range(60):
    for pad in ((16, PAD) if it % 2 else (PAD, 16)):
        t.setdefault(pad, []).append(step(pad, 3, 0) + step(pad, 9, 3))
    t.setdefault("flat", []).append(stepf(3) + stepf(9))
for c in (3, 9):
    o = [np.empty(N * c, np.float32) for _ in range(2)]
    for j in range(3):
        cl.enqueue_copy(q, o[0], state[16][c][j]); cl.enqueue_copy(q, o[1], state[PAD][c][j]); q.finish()
        assert np.array_equal(o[0].view(np.uint32), o[1].view(np.uint32)), (c, j)
a, b, f = (np.array(t[x][4:]) * 1e3 for x in (16, PAD, "flat"))
print(f"N={N} sh_dc+sh_rest: pad 16 {np.median(a):.3f} ms, pad {PAD} {np.median(b):.3f} ms, ratio {np.median(b / a):.3f} "
      f"(q25 {np.quantile(b / a, .25):.3f} q75 {np.quantile(b / a, .75):.3f}); flat kernel on the same elements {np.median(f):.3f} ms")
