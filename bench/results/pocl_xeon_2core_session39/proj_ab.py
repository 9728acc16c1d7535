"""In-process A/B of project.cl builds: project_fwd / project_bwd device ms on a fern state, alternating
REINGS_SCALAR_BUILTINS=1 (default) and =0 (define passed through _proj_defines)."""
import sys, os
from pathlib import Path
import numpy as np
sys.path.insert(0, "/work/main")
from reings.backends import set_queue_profiling
set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
run = Path("/tmp/s39/census_run/llff/reings/3views/fern")
z = np.load(run / f"checkpoints/{sys.argv[1]}.npz")
sh = np.concatenate([z["param/sh_dc"], z["param/sh_rest"]], axis=1)
g0 = Gaussians(means=z["param/means"], quats=z["param/quats"], log_scales=z["param/log_scales"],
               opacity_logits=z["param/opacity_logits"], sh=np.ascontiguousarray(sh))
cam = read_cameras_json(run / "cameras.json", split="train")[0].camera
be = OpenCLBackend("pocl")
orig = be._proj_defines
define = os.environ.get("AB_DEFINE", "REINGS_SCALAR_BUILTINS")
rng = np.random.default_rng(0)
vr = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32) * 1e-3
vd = rng.normal(size=(cam.height, cam.width)).astype(np.float32) * 1e-3
t = {}
for it in range(int(sys.argv[2]) if len(sys.argv) > 2 else 20):
    for v in (1, 0):
        be._proj_defines = lambda k, v=v: {**orig(k), define: v}
        g = Gaussians(means=g0.means + np.float32(1e-7 * (2 * it + v)), quats=g0.quats, log_scales=g0.log_scales,
                      opacity_logits=g0.opacity_logits, sh=g0.sh)
        be.render_vjp(g, cam, vr, vd, None)
        if it >= 2:
            for stage in ("project_fwd", "project_bwd"):
                if stage in be.last_profile:
                    t.setdefault((stage, v), []).append(be.last_profile[stage])
for stage in ("project_fwd", "project_bwd"):
    a, b = np.array(t[(stage, 1)]), np.array(t[(stage, 0)])
    print(f"{sys.argv[1]} n={len(g0)} {stage}: {define}=1 {np.median(a):.3f} ms, =0 {np.median(b):.3f} ms, ratio {np.median(a / b):.3f} (q25 {np.quantile(a / b, .25):.3f} q75 {np.quantile(a / b, .75):.3f}, {len(a)} pairs)")
