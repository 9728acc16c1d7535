"""Pass visits (popcount of the forward's hits) and box visits of the CPU forward on a checkpoint."""
import sys, time, numpy as np, pyopencl as cl
from ckscene import load
import bench_rasterize as B
from reings.backends.opencl.device import open_device
from reings.backends.opencl.rasterize import Rasterizer
g, cam, proj, bins = load(sys.argv[1])
W, H = cam.width, cam.height
n, k = len(g), len(bins.gid_from_isect)
h = open_device("pocl", profiling=True)
r = Rasterizer(h)
b = B._upload(h, proj, bins, W, H)
q = h.queue
ts = []
for i in range(8):
    e0 = r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
    e1 = r.fwd(None, None, None, None, None, n, b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], k, W, H, (0, 0, 0), prepared=True)
    q.finish(); ts.append(B._ms(e1))
hits = np.empty(k, np.uint32); cl.enqueue_copy(q, hits, r.hits); q.finish()
pc = np.unpackbits(hits.view(np.uint8)).reshape(-1, 32).sum(1)
# box visits: vectors of each pair's box (4x4 blocks, 16x16 tiles) for the pairs walked (all pairs: upper bound)
m = proj.means2d; 
print("K", k, "pass visits", int(pc.sum()), "fwd ms median", np.median(ts[2:]))
print("cycles/visit at 2 cores x 2.1 GHz:", np.median(ts[2:]) * 1e-3 * 2 * 2.1e9 / pc.sum())
