"""The photometric loss's SSIM kernels per element at four sizes, the four passes (fused=False) against a fused CPU
form (fused=True). The fused CPU kernels were not kept: this script ran against the two trees of
ssim_fused_not_kept.txt (the kernels are in git history only as this description; see docs/perf_notes.md §41).
OPENBLAS_NUM_THREADS=1 python ssim_fused_size.py (from the repository root)."""
import sys, numpy as np
sys.path.insert(0, '.')
from reings.backends.opencl import losses as L
from reings.backends.opencl.device import open_device
h = open_device("pocl", profiling=True)
for H, W in [(378, 504), (189, 252), (96, 128), (48, 64)]:
  for fused in (False, True):
    rng = np.random.default_rng(0)
    x = rng.random((H, W, 3), dtype=np.float32); y = rng.random((H, W, 3), dtype=np.float32)
    p = L.PhotometricCL(h, fused=fused)
    p(x, y, 0.8, 0.2)
    times = {}
    orig = p._typed
    def typed(name, *a):
        ev = orig(name, *a); times.setdefault(name, []).append(ev); return ev
    p._typed = typed
    for _ in range(22): p.enqueue(p.x, p.y, p.v, H, W, 0.8, 0.2, value=False)
    h.queue.finish()
    r = {k: float(np.median([(e.profile.end - e.profile.start) * 1e-6 for e in evs[2:]])) for k, evs in times.items()}
    print(H, W, fused, {k: round(v * 1e6 / (H * W * 3), 2) for k, v in r.items()}, "ns/elem; total ms", round(sum(r.values()), 3))
