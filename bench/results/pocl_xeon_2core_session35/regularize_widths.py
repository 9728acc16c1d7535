"""python bench/results/pocl_xeon_2core_session35/regularize_widths.py [N] [RUNS] (from the repository root): regularize_grads at REG_VW 1 against 8: device time (alternating, one process) and the outputs' bytes."""
import sys, numpy as np, pyopencl as cl
sys.path.insert(0, ".")
from reings.backends.opencl.device import open_device
from reings.backends.opencl.program import library_for
h = open_device("pocl", profiling=True)
lib = library_for(h)
ctx, q = h.context, h.queue
n = int(sys.argv[1]) if len(sys.argv) > 1 else 57153
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 20
rng = np.random.default_rng(0)
ls = (rng.normal(size=(n, 3)) * 1.0 - 4.0).astype(np.float32)
ls[:50] = ls[:50, :1]; ls[50:80, 1] = ls[50:80, 0]
lg = (rng.normal(size=n) * 2.0).astype(np.float32)
mf = cl.mem_flags
b_ls = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=ls)
b_lg = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=lg)
counts = np.array([n // 3, n - n // 3, 0, 0], np.int32)
res = {}
times = {1: [], 8: []}
for r in range(runs + 3):
    for vw in (1, 8):
        k = lib.get("regularize.cl", "regularize_grads", REGULARIZE_FP64=1, REG_VW=vw)
        b_c = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=counts)
        g_ls = np.full((n, 3), 1e-3, np.float32); g_lg = np.full(n, -1e-3, np.float32)
        b_gls = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=g_ls)
        b_glg = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=g_lg)
        items = -(-n // vw); wg = 256; gs = -(-items // wg) * wg
        ev = k(q, (gs,), (wg,), np.int32(n), b_ls, b_lg, b_c, np.int32(0), np.float64(0.002), np.float64(0.001),
               np.float64(0.001), b_gls, b_glg)
        ev.wait()
        if r >= 3:
            times[vw].append((ev.profile.end - ev.profile.start) * 1e-6)
        cl.enqueue_copy(q, g_ls, b_gls); cl.enqueue_copy(q, g_lg, b_glg); q.finish()
        res[vw] = (g_ls.copy(), g_lg.copy())
for vw in times:
    print("REG_VW", vw, "median ms", round(float(np.median(times[vw])), 4))
print("ratio of medians 8/1", round(float(np.median(times[8]) / np.median(times[1])), 3))
for i, name in enumerate(("v_log_scales", "v_logits")):
    a, b = res[1][i], res[8][i]
    print(name, "identical bytes" if np.array_equal(a.view(np.uint32), b.view(np.uint32)) else f"DIFFER in {np.count_nonzero(a != b)}")
