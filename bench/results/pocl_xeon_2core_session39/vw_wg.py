import sys, numpy as np, time
import os; R=os.environ.get('ROOT','/work/main'); sys.path.insert(0, R); sys.path.insert(0, R+'/tests')
from reings.backends import set_queue_profiling
set_queue_profiling(True)
import pyopencl as cl
from reings.backends.opencl.view_warp import ViewWarpCL
from test_view_warp import _images
rng = np.random.default_rng(0)
h, w, fx, b = 378, 504, 407.0, 0.4
y, x = np.mgrid[0:h, 0:w]
depth = (20.0 + 40.0 * x / w + 3.0 * np.sin(y / 17.0)).astype(np.float32)
depth[100:250, 150:300] = 8.0
virt, _, gt = _images(h, w, rng)
res = {}
for rnd in range(3):
  for wg in [int(a) for a in sys.argv[1:]]:
    vw = ViewWarpCL("pocl", wg=wg)
    ctx, q = vw.handle.context, vw.handle.queue
    mf = cl.mem_flags
    bufs = [cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for a in (virt, depth, gt)]
    ov, od = cl.Buffer(ctx, mf.READ_WRITE, virt.nbytes), cl.Buffer(ctx, mf.READ_WRITE, depth.nbytes)
    edges = vw.edges(bufs[2], h, w, out=cl.Buffer(ctx, mf.READ_WRITE, h*w*8))
    vw.enqueue(*bufs, ov, od, h, w, fx, b, edges=edges).wait()
    per = {}
    for _ in range(20):
        ev = vw.enqueue(*bufs, ov, od, h, w, fx, b, edges=edges); ev.wait()
        for name, e in vw.events:
            per.setdefault(name, []).append(1e-6 * (e.profile.end - e.profile.start))
    out = (np.empty_like(virt), np.empty_like(depth))
    cl.enqueue_copy(q, out[0], ov); cl.enqueue_copy(q, out[1], od)
    res.setdefault(wg, []).append(out)
    print(wg, ", ".join(f"{n} {np.median(v):.3f}" for n, v in per.items()), flush=True)
ws = sorted(res)
for wg in ws[1:]:
    print(wg, "same bits as", ws[0], all(np.array_equal(a, c) for a, c in zip(res[wg][0], res[ws[0]][0])))
