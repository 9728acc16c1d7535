import time, numpy as np, pyopencl as cl
from reings.backends import get_backend
be = get_backend("pocl")
ctx, q = be.handle.context, be.queue
from reings.backends.opencl.losses import SSIM_ROWS
k = be.kernel("photometric.cl", "loss_row_sums", SSIM_ROWS=SSIM_ROWS, SSIM_VW=16)
H, W = 378, 504
rng = np.random.default_rng(0)
mf = cl.mem_flags
a = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=rng.random(H * W * 3).astype(np.float32)) for _ in range(3)]
part = cl.Buffer(ctx, mf.READ_WRITE, H * 8)
ts = []
for r in range(30):
    q.finish(); t = time.perf_counter()
    k(q, (H,), None, a[0], a[1], a[2], part, np.int32(W), np.int32(H)); q.finish()
    ts.append(time.perf_counter() - t)
print("loss_row_sums median ms", np.median(ts[5:]) * 1e3)
