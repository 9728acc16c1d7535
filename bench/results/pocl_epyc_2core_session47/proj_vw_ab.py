"""In-process A/B of project.cl's lanes on a fern checkpoint: two backends, PROJ_VW 16 and 8 (the default
before session 47 on AVX2), their render_vjp calls alternating; project_fwd / project_bwd device ms and the outputs' bytes compared.
argv: CK.npz [its]"""
import sys
from pathlib import Path

import numpy as np

from reings.backends import set_queue_profiling

set_queue_profiling(True)
from reings.backends.opencl.backend import OpenCLBackend  # noqa: E402
from reings.io.cameras import read_cameras_json  # noqa: E402
from reings.types import Gaussians  # noqa: E402

ck = Path(sys.argv[1])
z = np.load(ck)
sh = np.concatenate([z["param/sh_dc"], z["param/sh_rest"]], axis=1)
g0 = Gaussians(means=z["param/means"], quats=z["param/quats"], log_scales=z["param/log_scales"],
               opacity_logits=z["param/opacity_logits"], sh=np.ascontiguousarray(sh))
cam = read_cameras_json(ck.parent.parent / "cameras.json", split="train")[0].camera
bes = {}
for vw in (16, 8):
    be = OpenCLBackend("pocl")
    be.proj_vw, be.proj_wg = vw, 512 // vw
    bes[vw] = be
rng = np.random.default_rng(0)
vr = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32) * 1e-3
vd = rng.normal(size=(cam.height, cam.width)).astype(np.float32) * 1e-3
t = {}
for it in range(int(sys.argv[2]) if len(sys.argv) > 2 else 20):
    outs = {}
    for vw, be in bes.items():
        g = Gaussians(means=g0.means + np.float32(1e-7 * it), quats=g0.quats, log_scales=g0.log_scales,
                      opacity_logits=g0.opacity_logits, sh=g0.sh)
        outs[vw] = be.render_vjp(g, cam, vr, vd, None)
        if it >= 2:
            for stage in ("project_fwd", "project_bwd"):
                t.setdefault((stage, vw), []).append(be.last_profile[stage])
    if it == 0:
        import dataclasses
        a, b = outs[16], outs[8]
        same = {f.name: np.array_equal(np.asarray(getattr(a, f.name)).view(np.uint8),
                                       np.asarray(getattr(b, f.name)).view(np.uint8)) for f in dataclasses.fields(a)}
        print("same bytes:", same)
for stage in ("project_fwd", "project_bwd"):
    a, b = np.array(t[(stage, 16)]), np.array(t[(stage, 8)])
    print(f"{ck.stem} n={len(g0)} {stage}: 16 lanes {np.median(a):.3f} ms, 8 lanes {np.median(b):.3f} ms, ratio "
          f"{np.median(a / b):.3f} (q25 {np.quantile(a / b, .25):.3f} q75 {np.quantile(a / b, .75):.3f}, {len(a)} pairs)")
