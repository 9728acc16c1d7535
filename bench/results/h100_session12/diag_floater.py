"""Session 12: which Gaussians make the collapsed flower run (call 2, flower_drop_diag = call 1's
flower_drop seed 2, 17.611 dB) fail on its test views 8 and 24.

    python bench/results/h100_session12/diag_floater.py RUN_DIR

RUN_DIR: the run folder (gaussians.ply, cameras.json) that came back from the call as
diag_model.tar (the model itself is not committed). Renders on PoCL: per Gaussian, the importance
(alpha*T summed over pixels) in the training views and in test view 8, and for the top one its
footprint alone and in the full model in every camera. Output: diag_floater.txt next to this file.
"""
import sys

import numpy as np

from reings.backends import get_backend
from reings.io.cameras import read_cameras_json
from reings.io.ply import read_ply

run = sys.argv[1]
g = read_ply(f"{run}/gaussians.ply")
recs = read_cameras_json(f"{run}/cameras.json")
b = get_backend("pocl")
train = [r for r in recs if r.split == "train"]
imp = lambda m, r: b.render(m, r.camera, (0, 0, 0), 0.01, want_importance=True).importance  # noqa: E731
omega_tr = sum(imp(g, r) for r in train)
t8 = [r for r in recs if r.name == "image008"][0]
o8 = imp(g, t8)
print(f"{len(g)} Gaussians; train views {[r.name for r in train]}; unseen by every training view: {(omega_tr == 0).sum()}")
op = 1 / (1 + np.exp(-g.opacity_logits))
for i in np.argsort(-o8)[:5]:
    print(f"gid {i}: importance test 8 {o8[i]:.0f}, training views {omega_tr[i]:.0f}, opacity {op[i]:.3f}, "
          f"scales {np.round(np.exp(g.log_scales[i]), 2)}, mean {np.round(g.means[i], 2)}, sh dc {np.round(g.sh[i, 0], 2)}")
top = int(np.argmax(o8))
one = g.subset(np.array([top]))
for r in recs:
    V = r.camera.viewmat
    c = -V[:3, :3].T @ V[:3, 3]
    a = b.render(one, r.camera, (0, 0, 0), 0.01).alpha
    print(f"{r.split:5s} {r.name}: camera centre {np.round(c, 2)}, gid {top} alone covers {(a > 1 / 255).sum()} px, "
          f"importance in the full model {imp(g, r)[top]:.0f}")
