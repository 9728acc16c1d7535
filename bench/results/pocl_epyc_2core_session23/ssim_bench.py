"""The photometric loss's kernels at 504x378 on one device, per kernel (profiled, median of 10 after 2):
    SCHED=0|1 python ssim_bench.py TREE        (SCHED: PhotometricCL's cpu_schedule, 1 = a work-item per 16 rows)
Trees before 9b7d40c have no cpu_schedule argument: run them with SCHED unset."""
import os
import sys

import numpy as np

sys.path.insert(0, sys.argv[1] if len(sys.argv) > 1 else ".")
from reings.backends.opencl.device import open_device  # noqa: E402
from reings.backends.opencl.losses import PhotometricCL  # noqa: E402

h = open_device(os.environ.get("DEVICE", "pocl"), profiling=True)
sched = os.environ.get("SCHED")
p = PhotometricCL(h) if sched is None else PhotometricCL(h, cpu_schedule=sched == "1")
H, W = 378, 504
rng = np.random.default_rng(0)
x = rng.random((H, W, 3), dtype=np.float32)
y = rng.random((H, W, 3), dtype=np.float32)
loss, v = p(x, y, 0.8, 0.2)
times: dict = {}
orig = p._typed


def typed(name, *a):
    ev = orig(name, *a)
    times.setdefault(name, []).append(ev)
    return ev


p._typed = typed
for _ in range(12):
    p.enqueue(p.x, p.y, p.v, H, W, 0.8, 0.2)
h.queue.finish()
tot = 0.0
for k, evs in times.items():
    ms = float(np.median([(e.profile.end - e.profile.start) * 1e-6 for e in evs[2:]]))
    tot += ms
    print(f"{k:16s} {ms:8.2f} ms")
print("total", round(tot, 2), "loss", loss, "sum |v|", float(np.abs(v).sum()))
