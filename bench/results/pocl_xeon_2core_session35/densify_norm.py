# densify_accumulate.cl with the norm as hypot (XP_HYPOT=1, an experiment define in densify.h, removed) against
# sqrt(x x + y y) in double (0, kept): device time alternating in one process, and the bytes. Run from the repository root.
import sys, numpy as np, pyopencl as cl
sys.path.insert(0, ".")
from reings.backends.opencl.device import open_device
from reings.backends.opencl.program import library_for
h = open_device("pocl", profiling=True); lib = library_for(h); ctx, q = h.context, h.queue
n = 57153; rng = np.random.default_rng(0); mf = cl.mem_flags
radii = np.where(rng.random(n) < 0.9, rng.integers(1, 40, n), 0).astype(np.int32)
vp = (rng.normal(size=(n, 10)) * 1e-4).astype(np.float32)
b_r = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=radii); b_v = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=vp)
t = {0: [], 1: []}; out = {}
for r in range(23):
    for xp in (1, 0):
        k = lib.get("densify_accumulate.cl", "densify_accumulate", DENSIFY_FP64=1, XP_HYPOT=xp)
        acc = np.zeros(n, np.float32); cnt = np.zeros(n, np.int32); mr = np.zeros(n, np.float32)
        ba = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=acc); bc = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=cnt); bm = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=mr)
        ev = k(q, (-(-n // 256) * 256,), (256,), np.int32(n), b_r, b_v, np.float64(252.0), np.float64(189.0), ba, bc, bm); ev.wait()
        if r >= 3: t[xp].append((ev.profile.end - ev.profile.start) * 1e-6)
        cl.enqueue_copy(q, acc, ba); q.finish(); out[xp] = acc
print("hypot median ms", np.median(t[1]), "sqrt median ms", np.median(t[0]), "ratio", np.median(t[0]) / np.median(t[1]))
print("identical bytes" if np.array_equal(out[0].view(np.uint32), out[1].view(np.uint32)) else f"differ in {np.count_nonzero(out[0] != out[1])}")
