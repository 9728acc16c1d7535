"""python prof.py STATE RUNS [REPO] [RUN_DIR]: per-stage device ms of render_vjp on a fern checkpoint (PoCL), medians over runs."""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, sys.argv[3] if len(sys.argv) > 3 else str(Path(__file__).resolve().parents[3]))
from reings.backends import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
run = Path(sys.argv[4] if len(sys.argv) > 4 else "/tmp/s39/census_run_new/llff/reings/3views/fern")  # a fern run with checkpoints
z = np.load(run / f"checkpoints/{sys.argv[1]}.npz")
sh = np.concatenate([z["param/sh_dc"], z["param/sh_rest"]], axis=1)
g0 = Gaussians(means=z["param/means"], quats=z["param/quats"], log_scales=z["param/log_scales"],
               opacity_logits=z["param/opacity_logits"], sh=np.ascontiguousarray(sh))
cam = read_cameras_json(run / "cameras.json", split="train")[0].camera
be = OpenCLBackend("pocl")
rng = np.random.default_rng(0)
vr = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32) * 1e-3
t = {}
for it in range(int(sys.argv[2])):
    g = Gaussians(means=g0.means + np.float32(1e-7 * it), quats=g0.quats, log_scales=g0.log_scales,
                  opacity_logits=g0.opacity_logits, sh=g0.sh)
    be.render_vjp(g, cam, vr, None, None)
    if it >= 2:
        for k, v in be.last_profile.items():
            t.setdefault(k, []).append(v)
print(len(g0), {k: round(float(np.median(v)), 3) for k, v in t.items()})
