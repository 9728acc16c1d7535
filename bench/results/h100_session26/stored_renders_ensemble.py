# session 26, before building --ensemble: the masked PSNR of the mean image of 2 and 3 of session 20's DTU scan24
# 3-view runs (their test renders, kept on the session machine under /tmp/rs7, /tmp/rs8; not in the repository).
# Usage: python stored_renders_ensemble.py RUN_BASE... (RUN_BASE: .../3views/scan24; its _seed1, _seed2 beside it)
import sys, os, glob, itertools, numpy as np, cv2
import reings
from reings.metrics import psnr, ssim
sc = reings.load_scene("/work/shared/data/dtu/scan24", "dtu")
names = [os.path.basename(n) for n in sc.names]
def load(d):
    out = {}
    for f in sorted(glob.glob(d + "/renders/*.png")):
        out[os.path.basename(f)] = cv2.cvtColor(cv2.imread(f), cv2.COLOR_BGR2RGB).astype(np.float64) / 255
    return out
for base in sys.argv[1:]:
    runs = [load(base + s) for s in ("", "_seed1", "_seed2")]
    keys = sorted(runs[0])
    idx = [names.index(k) for k in keys]
    def score(imgs_per_key, fn=psnr):
        return np.mean([fn(imgs_per_key[j], sc.images[i], mask=sc.masks[i]) for j, i in enumerate(idx)])
    single = [score([r[k] for k in keys]) for r in runs]
    pairs = [score([(a[k] + b[k]) / 2 for k in keys]) for a, b in itertools.combinations(runs, 2)]
    tri = score([sum(r[k] for r in runs) / 3 for k in keys])
    med = score([np.median([r[k] for r in runs], axis=0) for k in keys])
    print(base, "single", np.round(single, 3), np.mean(single).round(3), "pairs", np.round(pairs, 3), np.mean(pairs).round(3), "tri", round(tri, 3), "median3", round(med, 3))
