import sys, time, numpy as np
sys.path.insert(0, ".")
from reings.backends.opencl.device import open_device
from reings.backends.opencl.sort import RadixSort
import pyopencl as cl
h = open_device("pocl")
q = h.queue
rng = np.random.default_rng(0)
res = {}
sorters = {b: RadixSort(h, max_bits=b) for b in (8, 11)}
cases = {"depth55k": (rng.uniform(2, 8, 55000).astype(np.float32).view(np.uint32), 0, 32),
         "tile200k": (rng.integers(0, 768, 200000).astype(np.uint32), 0, 10)}
mf = cl.mem_flags
for name, (keys, b0, b1) in cases.items():
    n = len(keys)
    vals = np.arange(n, dtype=np.uint32)
    kb = cl.Buffer(h.context, mf.READ_WRITE, keys.nbytes); vb = cl.Buffer(h.context, mf.READ_WRITE, vals.nbytes)
    outs = {}
    t = {8: [], 11: []}
    for r in range(30):
        for b, s in sorters.items():
            cl.enqueue_copy(q, kb, keys); cl.enqueue_copy(q, vb, vals); q.finish()
            t0 = time.perf_counter()
            res_ = s.sort_pairs(kb, vb, n, begin_bit=b0, end_bit=b1)
            q.finish()
            t[b].append((time.perf_counter() - t0) * 1e3)
            if r == 0:
                ko, vo = res_[:2] if isinstance(res_, tuple) else (kb, vb)
                a = np.empty(n, np.uint32); cl.enqueue_copy(q, a, vo); outs[b] = a
    same = np.array_equal(outs[8], outs[11])
    print(name, {b: round(float(np.median(v[3:])), 3) for b, v in t.items()}, "same order" if same else "DIFFER")
