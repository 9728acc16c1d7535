"""Per visited pair (forward, ignoring stops): box vectors (the alpha box in 4x4 blocks of the tile) vs vectors past the cut."""
import sys, numpy as np
from pathlib import Path
from reings.backends import reference as ref
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
ck = sys.argv[1]
z = np.load(ck); lg = z["param/opacity_logits"]
sh = z["param/sh_dc"]
if "param/sh_rest" in z and z["param/sh_rest"].size: sh = np.concatenate([sh, z["param/sh_rest"]], 1)
g = Gaussians(z["param/means"], z["param/quats"], z["param/log_scales"], lg, sh)
cam = read_cameras_json(Path(ck).resolve().parents[1] / 'cameras.json')[0].camera
W, H = cam.width, cam.height
proj = ref.project_fwd(g, cam); bins = ref.bin(proj, W, H)
m = proj.means2d.astype(np.float64); con = proj.conics.astype(np.float64); op = proj.opacities.astype(np.float64).ravel()
A, B, C = con[:, 0], con[:, 1], con[:, 2]; det = A * C - B * B
lo = op * 255
with np.errstate(all='ignore'):
    ln = np.log(lo); ex = np.sqrt(2 * ln * C / det) * 1.01 + 0.5; ey = np.sqrt(2 * ln * A / det) * 1.01 + 0.5
    cut = -ln - 1e-3
xlo = m[:, 0] - ex; xhi = m[:, 0] + ex; ylo = m[:, 1] - ey; yhi = m[:, 1] + ey
tr = bins.tile_ranges; tiles_x = (W + 15) // 16
ys, xs = np.mgrid[0:16, 0:16]
box = hit = 0
for t in range(len(tr)):
    s, e = tr[t]
    if e <= s: continue
    ty, tx = divmod(t, tiles_x); gid = bins.gid_from_isect[s:e]
    x0, y0 = tx * 16, ty * 16
    c0 = np.clip(np.floor(xlo[gid]).astype(int) - x0, 0, None) // 4; c1 = np.clip(np.floor(xhi[gid]).astype(int) - x0, None, 15) // 4
    r0 = np.clip(np.floor(ylo[gid]).astype(int) - y0, 0, None) // 4; r1 = np.clip(np.floor(yhi[gid]).astype(int) - y0, None, 15) // 4
    box += (np.clip(c1 - c0 + 1, 0, None) * np.clip(r1 - r0 + 1, 0, None)).sum()
    px = x0 + xs + 0.5; py = y0 + ys + 0.5
    dx = m[gid, 0][:, None, None] - px[None]; dy = m[gid, 1][:, None, None] - py[None]
    pw = -0.5 * (A[gid][:, None, None] * dx * dx + C[gid][:, None, None] * dy * dy) - B[gid][:, None, None] * dx * dy
    hit += (pw >= cut[gid][:, None, None]).reshape(-1, 4, 4, 4, 4).any((2, 4)).sum()
print(Path(ck).name, "K", len(bins.gid_from_isect), "box vectors", box, "past the cut", hit, "ratio %.2f" % (box / hit))
