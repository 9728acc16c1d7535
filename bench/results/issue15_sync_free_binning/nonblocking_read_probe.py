"""Does a non-blocking read return before the queue drains on this driver? pageable vs pinned."""
import time, numpy as np, pyopencl as cl
from reings.backends.opencl.device import open_device
from reings.backends.opencl.bin_counts import CountsRing
from collections import deque
h = open_device("cuda")
ctx, q = h.context, h.queue
k = cl.Kernel(cl.Program(ctx, """
__kernel void spin(__global float *a, int iters) { float x = a[get_global_id(0)];
  for (int i = 0; i < iters; ++i) x = x * 1.0000001f + 1e-7f; a[get_global_id(0)] = x; }""").build(), "spin")
buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * 1024)
cl.enqueue_fill_buffer(q, buf, np.float32(1), 0, 4 * 1024)
ring = CountsRing(h)
pageable = np.empty(2, np.uint32)
for rep in range(3):
    for what in ("pageable", "pinned", "blocking"):
        k(q, (1024,), None, buf, np.int32(3_000_000)); q.flush()
        t0 = time.perf_counter()
        if what == "pageable":
            ev = cl.enqueue_copy(q, pageable, buf, is_blocking=False)
        elif what == "pinned":
            ev = ring.read(buf, deque())
        else:
            ev = cl.enqueue_copy(q, pageable, buf, is_blocking=True)
        t1 = time.perf_counter()
        q.finish()
        t2 = time.perf_counter()
        print(f"{what:9s} enqueue {1e3*(t1-t0):8.3f} ms, then finish {1e3*(t2-t1):8.3f} ms", flush=True)
        del ev
