"""Pixel vectors with a lane above the alpha cut (no T, no stopping) per vector shape, on a perf scene (A, B, C).

    python vector_counts_scene.py A
"""
import numpy as np, sys
from reings.backends import reference as ref
from reings.bench_scenes import perf_scene
scene = sys.argv[1] if len(sys.argv)>1 else 'A'
g, cam = perf_scene(scene)
W,H = cam.width, cam.height
proj = ref.project_fwd(g, cam)
bins = ref.bin(proj, W, H)
print({k: getattr(proj,k).shape for k in ['means2d','conics','opacities']}, len(bins.gid_from_isect))
tr = bins.tile_ranges; tiles_x = (W+15)//16
m = proj.means2d.astype(np.float64); con = proj.conics.astype(np.float64); op = proj.opacities.astype(np.float64).ravel()
cut = -np.log(255*op) - 1e-3
ys, xs = np.mgrid[0:16,0:16]
tot = dict(pairs=0, v81=0, v42=0, v24=0, v44=0,v161=0, lanes=0)
T = len(tr)
for t in range(T):
    s,e = tr[t]
    if e<=s: continue
    ty, tx = divmod(t, tiles_x)
    gid = bins.gid_from_isect[s:e]
    px = tx*16 + xs + 0.5; py = ty*16 + ys + 0.5
    inside = (px < W) & (py < H)
    dx = m[gid,0][:,None,None] - px[None]; dy = m[gid,1][:,None,None] - py[None]
    A = con[gid,0][:,None,None]; B = con[gid,1][:,None,None]; C = con[gid,2][:,None,None]
    pw = -0.5*(A*dx*dx + C*dy*dy) - B*dx*dy
    ok = (pw >= cut[gid][:,None,None]) & (pw <= 0) & inside[None]
    tot['pairs'] += ok.sum()
    n = len(gid)
    tot['v81'] += ok.reshape(n,16,2,8).any(-1).sum()
    tot['v161'] += ok.reshape(n,16,16).any(-1).sum()
    tot['v42'] += ok.reshape(n,8,2,4,4).any((2,4)).sum()
    tot['v24'] += ok.reshape(n,4,4,8,2).any((2,4)).sum()
    tot['v44'] += ok.reshape(n,4,4,4,4).any((2,4)).sum()
print(scene, tot)
for k,lanes in [('v81',8),('v42',8),('v24',8),('v161',16),('v44',16)]:
    print(k, 'util %.3f'%(tot['pairs']/(tot[k]*lanes)), 'vectors', tot[k])
