# Session 42: call 5's flower models (RUN = flower_seed2 / flower_seed1 folders): the ten Gaussians that cover test
# view 008 most (3-sigma box overlap with its frame x opacity), each with its depth, radius and frame position in the
# three training views; and the model's depth percentiles per camera. Usage: python floater_near.py RUN
import json, sys
import numpy as np
from reings.io.ply import read_ply

run = sys.argv[1]
g = read_ply(f"{run}/gaussians.ply")
cams = {c["img_name"]: c for c in json.load(open(f"{run}/cameras.json"))}
mu = np.asarray(g.means, np.float64)
s = np.exp(np.asarray(g.log_scales, np.float64)).max(1)
op = 1 / (1 + np.exp(-np.asarray(g.opacity_logits, np.float64)))
col = np.asarray(g.sh)[:, 0, :] * 0.28209479177387814 + 0.5


def proj(c):  # cameras.json: rotation = camera-to-world, position = centre
    x = (mu - np.array(c["position"])) @ np.array(c["rotation"])
    z = x[:, 2]
    u, v = c["fx"] * x[:, 0] / z + c["cx"], c["fy"] * x[:, 1] / z + c["cy"]
    r = 3 * c["fx"] * s / np.maximum(z, 1e-6)
    ou = np.clip(np.minimum(u + r, c["width"]) - np.maximum(u - r, 0), 0, None)
    ov = np.clip(np.minimum(v + r, c["height"]) - np.maximum(v - r, 0), 0, None)
    return z, u, v, r, ou * ov / (c["width"] * c["height"])


for name, c in cams.items():
    z = proj(c)[0]
    print(f"{name} {c['split']}: depth min {z.min():.2f}, 1st percentile {np.percentile(z, 1):.2f}, median {np.median(z):.2f}")
z8, u8, v8, r8, cov8 = proj(cams["image008"])
for i in np.argsort(-cov8 * op)[:10]:
    line = (f"g{i} depth@008 {z8[i]:.1f} r@008 {r8[i]:.0f}px cover@008 {cov8[i]:.2f} opacity {op[i]:.2f} "
            f"scale {s[i]:.2f} colour {np.round(col[i], 2)}")
    for t in ("image001", "image017", "image033"):
        z, u, v, r, cov = proj(cams[t])
        line += f" | {t[-3:]}: depth {z[i]:.1f} u {u[i]:.0f} v {v[i]:.0f} r {r[i]:.0f}px"
    print(line)
