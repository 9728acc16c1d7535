import time, numpy as np, pyopencl as cl
from reings.backends.opencl.device import open_device
h = open_device("pocl", profiling=False)
ctx, q = h.context, h.queue
prg = cl.Program(ctx, """__kernel void k(__global float *a, int m){ float x = a[get_global_id(0)]; for (int i = 0; i < m; ++i) x = x * 0.999f + 0.5f; a[get_global_id(0)] = x; }""").build()
k = prg.k
n = 1 << 16
buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * n)
host = np.empty(4, np.float32)
for m in (50, 400):
    for mode in ("read", "noread", "read", "noread"):
        q.finish(); t = time.perf_counter()
        for i in range(200):
            k(q, (n,), None, buf, np.int32(m))
            if mode == "read": cl.enqueue_copy(q, host, buf, is_blocking=True)
            k(q, (n,), None, buf, np.int32(m))
        q.finish(); print(m, mode, "ms per pair %.3f" % ((time.perf_counter() - t) / 200 * 1e3))
