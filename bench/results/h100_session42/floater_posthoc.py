# Session 42: call 5's flower models (2,2,1 share 1,0.5,1; seed 2 collapsed, seed 1 not) with the Gaussians whose
# centre no training view frames (margin: a fraction of the image size on every side) dropped after the fit, each
# view rendered on PoCL against its image. Usage (in a run folder's parent): python floater_posthoc.py RUN DATA/llff/flower/images_8
import sys, numpy as np, cv2, os
from reings.io.ply import read_ply
from reings.io.cameras import read_cameras_json
from reings.rendering import render
from dataclasses import replace
run, imgdir = sys.argv[1], sys.argv[2]
g = read_ply(f'{run}/gaussians.ply')
recs = read_cameras_json(f'{run}/cameras.json')
train = [r for r in recs if r.split == 'train']
files = {os.path.splitext(f)[0]: f for f in os.listdir(imgdir)}
def centre_inside(cam, margin):
    mu = np.asarray(g.means, np.float64)
    x = mu @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    z = x[:, 2]; zs = np.where(z > 1e-6, z, 1)
    u = cam.K[0, 0] * x[:, 0] / zs + cam.K[0, 2]; v = cam.K[1, 1] * x[:, 1] / zs + cam.K[1, 2]
    mw, mh = margin * cam.width, margin * cam.height
    return (z > 0.01) & (u > -mw) & (u < cam.width + mw) & (v > -mh) & (v < cam.height + mh)
def psnr(a, b): return -10 * np.log10(np.mean((a - b) ** 2))
def subset(keep):
    return type(g)(**{f: np.asarray(getattr(g, f))[keep] for f in g.__dataclass_fields__})
for margin in (None, 0.0, 0.25):
    if margin is None:
        gg, n = g, 0
    else:
        keep = np.zeros(len(g), bool)
        for r in train: keep |= centre_inside(r.camera, margin)
        gg, n = subset(keep), int((~keep).sum())
    out = []
    for r in recs:
        gt = cv2.imread(os.path.join(imgdir, files[r.name]))[:, :, ::-1].astype(np.float32) / 255
        im = np.clip(render(gg, r.camera, device='pocl').rgb, 0, 1)
        out.append(f'{r.split[:2]}{r.name[-3:]} {psnr(im, gt):.2f}')
    print('margin', margin, 'pruned', n, ' '.join(out), flush=True)
