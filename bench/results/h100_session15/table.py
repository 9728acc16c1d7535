"""Per-variant table of a call's runs: python bench/results/h100_session15/table.py bench/results/h100_session15/call1
(variant, scene, views): PSNR per seed = mean, SSIM, LPIPS (VGG, rescored from the 8-bit renders), final Gaussians, seconds."""
import collections, glob, gzip, json, sys

import numpy as np

root = sys.argv[1].rstrip("/")
rows = collections.defaultdict(list)
for f in sorted(glob.glob(f"{root}/*/*/*/*views/*/metrics.json*")):
    m = json.load(gzip.open(f) if f.endswith(".gz") else open(f))
    name = f[len(root) + 1:].split("/")[0]
    rows[(name, m["scene"], m["views"])].append((m["seed"], m["mean"]["psnr"], m["mean"]["ssim"], m["mean"].get("lpips", float("nan")),
                                                 m["gaussians"].get("final_prune"), m["seconds"]["method"]))
for k, v in sorted(rows.items()):
    v.sort()
    p = [x[1] for x in v]
    print(k, " / ".join(f"{x:.2f}" for x in p), f"= {np.mean(p):.2f}", f"ssim {np.mean([x[2] for x in v]):.3f} lpips {np.mean([x[3] for x in v]):.3f}",
          "G", [x[4] for x in v], "s", [round(x[5]) for x in v])
