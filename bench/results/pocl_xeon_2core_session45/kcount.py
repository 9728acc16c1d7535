"""K of reference.bin with whole rects and with BIN_TIGHT on a fit's checkpoints (views 0-2; with the hard pass's opacity 0.99 too):
    git apply bench/results/pocl_xeon_2core_session45/bin_tight.patch    (on 53685df: BIN_TIGHT was not kept)
    python bench/results/pocl_xeon_2core_session45/kcount.py RUN/checkpoints/STAGE.npz ...   (from the repository root)"""
import sys, numpy as np
sys.path.insert(0, '.')
from pathlib import Path
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
from reings.backends import reference as R
for ck in sys.argv[1:]:
    z = np.load(ck)
    sh = z["param/sh_dc"]
    if "param/sh_rest" in z and z["param/sh_rest"].size: sh = np.concatenate([sh, z["param/sh_rest"]], axis=1)
    for ov in (None, 0.99):
        g = Gaussians(z["param/means"], z["param/quats"], z["param/log_scales"], z["param/opacity_logits"], sh)
        cams = read_cameras_json(str(Path(ck).parents[1] / "cameras.json"))
        ks = []
        for view in range(3):
            cam = cams[view].camera
            p = R.project_fwd(g, cam, opacity_override=ov)
            a = len(R.bin(p, cam.width, cam.height, tight=False).gid_from_isect)
            b = len(R.bin(p, cam.width, cam.height).gid_from_isect)
            ks.append((a, b))
        print(Path(ck).name, "override", ov, ks, "ratio %.3f" % (sum(b for a, b in ks) / sum(a for a, b in ks)))
