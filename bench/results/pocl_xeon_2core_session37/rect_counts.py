"""The CPU forward's pass-1 sets against an analytic bound (measured, not built; docs/perf_notes.md §33): per (tile,
Gaussian) pair of a checkpoint's training view, the 4 x 4 blocks with a pixel centre past the cut (float64) against
the blocks whose centre rectangle's maximum power (the concave quadratic's maximum over the rectangle: its centre if
inside, else the best of the four edges' 1-D maxima) is past it; asserts the bound is a superset.

    python rect_counts.py RUN/checkpoints/STAGE.npz"""
import sys, numpy as np
sys.path.insert(0, "/work/main/bench")
from pathlib import Path
from reings.backends import reference as ref
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
ck = sys.argv[1]; opac = float(sys.argv[2]) if len(sys.argv) > 2 else None
z = np.load(ck); lg = z["param/opacity_logits"]
if opac: lg = np.full_like(lg, np.log(opac/(1-opac)))
sh = z["param/sh_dc"]
if "param/sh_rest" in z and z["param/sh_rest"].size: sh = np.concatenate([sh, z["param/sh_rest"]], 1)
g = Gaussians(z["param/means"], z["param/quats"], z["param/log_scales"], lg, sh)
cam = read_cameras_json(Path(ck).resolve().parents[1] / 'cameras.json')[0].camera
W, H = cam.width, cam.height
proj = ref.project_fwd(g, cam); bins = ref.bin(proj, W, H)
tr = bins.tile_ranges; tiles_x = (W + 15) // 16
m = proj.means2d.astype(np.float64); con = proj.conics.astype(np.float64); op = proj.opacities.astype(np.float64).ravel()
with np.errstate(divide='ignore'): cut = -np.log(255 * op) - 1e-3
ys, xs = np.mgrid[0:16, 0:16]
exact = rect = grad = K = 0
for t in range(len(tr)):
    s, e = tr[t]
    if e <= s: continue
    ty, tx = divmod(t, tiles_x); gid = bins.gid_from_isect[s:e]; K += e - s
    px = tx * 16 + xs + 0.5; py = ty * 16 + ys + 0.5
    dx = m[gid, 0][:, None, None] - px[None]; dy = m[gid, 1][:, None, None] - py[None]
    A = con[gid, 0][:, None, None]; B = con[gid, 1][:, None, None]; C = con[gid, 2][:, None, None]
    pw = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
    hit = (pw >= cut[gid][:, None, None]).reshape(-1, 4, 4, 4, 4).any((2, 4))  # [n, by, bx]
    exact += hit.sum()
    # rectangle max over each 4x4 block's centre box [x0+.5, x0+3.5] x [y0+.5, y0+3.5]
    bx = tx * 16 + np.arange(4) * 4; by = ty * 16 + np.arange(4) * 4
    X0 = bx[None, None, :] + 0.5; X1 = X0 + 3.0; Y0 = by[None, :, None] + 0.5; Y1 = Y0 + 3.0
    u = m[gid, 0][:, None, None]; v = m[gid, 1][:, None, None]
    a = con[gid, 0][:, None, None]; b = con[gid, 1][:, None, None]; c = con[gid, 2][:, None, None]
    def f(x, y):
        ddx = u - x; ddy = v - y
        return -0.5 * (a * ddx * ddx + c * ddy * ddy) - b * ddx * ddy
    inside = (u >= X0) & (u <= X1) & (v >= Y0) & (v <= Y1)
    best = np.where(inside, 0.0, -np.inf)
    for yy in (Y0, Y1):  # horizontal edges: maximise over x in [X0, X1]; d/dx f = a(u-x) + b(v-y) = 0
        xs_ = np.clip(u + b * (v - yy) / a, X0, X1); best = np.maximum(best, f(xs_, yy))
    for xx in (X0, X1):
        ys_ = np.clip(v + b * (u - xx) / c, Y0, Y1); best = np.maximum(best, f(xx, ys_))
    rh = best >= cut[gid][:, None, None]
    assert not (hit & ~rh).any()
    rect += rh.sum()
print(Path(ck).name, opac, "K", K, "exact hit vectors", exact, "rect-max", rect, "ratio %.3f" % (rect / exact))
