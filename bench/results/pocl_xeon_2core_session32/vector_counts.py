"""Pixel vectors a CPU rasterizer forward evaluates (an exp) per vector shape, on a reings checkpoint.

    python vector_counts.py RUN/checkpoints/coarse.npz [0.99]   # the second argument: every opacity (hard pass)
    python vector_counts.py A                                   # a perf scene (reings.bench_scenes)

float64 numpy: per tile, front to back, the pixels still active (not stopped by T_MIN) whose power is above
the alpha cut, grouped by vector shape; util = active pairs / (vectors x lanes)."""
import sys
from pathlib import Path

import numpy as np
from reings.backends import reference as ref
from reings.io.cameras import read_cameras_json
from reings.types import Gaussians
ck, opac = sys.argv[1], (float(sys.argv[2]) if len(sys.argv)>2 else None)
if ck in ("A", "B", "C"):  # a perf scene (reings.bench_scenes): the "ignoring T" column is its count
    from reings.bench_scenes import perf_scene
    g, cam = perf_scene(ck)
else:
    z = np.load(ck)
    lg = z["param/opacity_logits"]
    if opac: lg = np.full_like(lg, np.log(opac/(1-opac)))
    sh = z["param/sh_dc"]
    if "param/sh_rest" in z and z["param/sh_rest"].size:
        sh = np.concatenate([sh, z["param/sh_rest"]], 1)
    g = Gaussians(z["param/means"], z["param/quats"], z["param/log_scales"], lg, sh)
    cam = read_cameras_json(Path(ck).resolve().parents[1] / 'cameras.json')[0].camera
W,H = cam.width, cam.height
proj = ref.project_fwd(g, cam); bins = ref.bin(proj, W, H)
tr = bins.tile_ranges; tiles_x = (W+15)//16
m = proj.means2d.astype(np.float64); con = proj.conics.astype(np.float64); op = proj.opacities.astype(np.float64).ravel()
with np.errstate(divide='ignore'): cut = -np.log(255*op) - 1e-3
ys, xs = np.mgrid[0:16,0:16]
lay = {'8x1':(8,1),'4x2':(4,2),'16x1':(16,1),'4x4':(4,4),'8x2':(8,2)}
tot = {k:0 for k in lay}; totbox={k:0 for k in lay}; visited=0; K=0; pairs_act=0
def blocks(mask, bw, bh):  # mask [n,16,16] -> [n, nb] any
    n=mask.shape[0]
    return mask.reshape(n,16//bh,bh,16//bw,bw).any((2,4)).reshape(n,-1)
for t in range(len(tr)):
    s,e = tr[t]
    if e<=s: continue
    K += e-s
    ty, tx = divmod(t, tiles_x)
    gid = bins.gid_from_isect[s:e]
    px = tx*16 + xs + 0.5; py = ty*16 + ys + 0.5
    inside = (px < W) & (py < H)
    dx = m[gid,0][:,None,None] - px[None]; dy = m[gid,1][:,None,None] - py[None]
    A = con[gid,0][:,None,None]; B = con[gid,1][:,None,None]; C = con[gid,2][:,None,None]
    pw = -0.5*(A*dx*dx + C*dy*dy) - B*dx*dy
    al = np.minimum(op[gid][:,None,None]*np.exp(pw), 0.99)
    ok = (pw <= 0) & (al >= 1/255) & inside[None]
    a = np.where(ok, al, 0.0)
    Tb = np.cumprod(np.concatenate([np.ones((1,16,16)), 1-a[:-1]]),0)  # T before k
    stopk = (Tb*(1-a) < 1e-4) & ok
    stopped_before = np.cumsum(stopk,0) - stopk > 0  # stopped at an earlier k
    active = ~stopped_before & inside[None]
    # loop exits after the k where all stopped
    alldone = (~active).all((1,2))
    nvis = (np.argmax(alldone)) if alldone.any() else len(gid)
    visited += nvis
    cutok = (pw >= cut[gid][:,None,None]) & active
    pairs_act += (ok & active).sum()
    # box from alpha-box: approximate by pw>=cut region ignoring active
    anyc = (pw >= cut[gid][:,None,None]) & inside[None]
    for k,(bw,bh) in lay.items():
        tot[k] += blocks(cutok[:nvis],bw,bh).sum()
        totbox[k] += blocks(anyc[:nvis],bw,bh).sum()
print(ck.split('/')[-1], opac, 'K',K,'visited',visited,'active ok pairs',pairs_act)
for k,(bw,bh) in lay.items():
    print(f"{k}: exp-vectors {tot[k]:>9d} (util {pairs_act/(tot[k]*bw*bh):.3f})  cut-box-vectors(any lane, ignoring T) {totbox[k]:>9d}")
