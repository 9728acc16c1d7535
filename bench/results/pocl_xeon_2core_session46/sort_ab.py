"""The tile sort (K pairs, 10-bit tile keys, sorted depth order inside) at max_bits 8 (two 5-bit passes) vs wider."""
import sys, time, numpy as np, pyopencl as cl
from reings.backends import get_backend
from reings.backends.opencl.sort import RadixSort
be = get_backend("pocl"); ctx, q = be.handle.context, be.queue; mf = cl.mem_flags
K, T = int(sys.argv[1]), int(sys.argv[2]); bits = [int(b) for b in sys.argv[3:]]
tb = int(np.ceil(np.log2(T)))
rng = np.random.default_rng(0)
keys = np.sort(rng.integers(0, T, K)).astype(np.uint32)  # emit order: per rank its tiles (here: random tiles)
keys = rng.permutation(keys).astype(np.uint32)
vals = np.arange(K, dtype=np.uint32)
want = np.argsort(keys, kind="stable")
sorters = [RadixSort(be.handle, max_bits=b) for b in bits]
kb, vb = cl.Buffer(ctx, mf.READ_WRITE, 4 * K), cl.Buffer(ctx, mf.READ_WRITE, 4 * K)
res = [[] for _ in bits]
for it in range(30):
    for j in (range(len(bits)) if it % 2 else reversed(range(len(bits)))):
        cl.enqueue_copy(q, kb, keys); cl.enqueue_copy(q, vb, vals); q.finish()
        t = time.perf_counter(); ko, vo, ev = sorters[j].sort_pairs(kb, vb, K, 0, tb); q.finish(); res[j].append(time.perf_counter() - t)
        out = np.empty(K, np.uint32); cl.enqueue_copy(q, out, vo); assert np.array_equal(out, want)
print("K", K, "T", T, "bits", bits, "ms", ["%.3f" % (np.median(r[4:]) * 1e3) for r in res], "ratios", ["%.3f" % np.median(np.array(res[j][4:]) / np.array(res[0][4:])) for j in range(len(bits))])
