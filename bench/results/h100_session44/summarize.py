"""Session 44's GPU runs (calls 1-2) against the default's digits (session 41, docs/results.md §52):
python3 summarize.py > summary.txt"""
import statistics as S

BASE = {("fern", 3): [22.25798297290443, 22.300828554576345, 22.213419818920027],
        ("flower", 3): [21.385892520600855, 21.3335903860959, 21.238297538858795],
        ("room", 3): [21.819226790583983, 21.79830277990556, 22.249035458618863],
        ("trex", 3): [22.2115, 22.5357, 22.5711],
        ("fern", 2): [21.3825, 21.4081, 21.1979],
        ("flower", 2): [20.0610, 20.0494, 19.9835]}
rows = {}
for f in ("call1_runs.txt", "call2_runs.txt"):
    for line in open(f):
        p = line.split()
        rows.setdefault((p[0], p[1], int(p[2])), {})[int(p[3])] = p
print("set scene views | PSNR per seed | mean ± sample sd | default's mean (same seeds) | Δ | SSIM mean | "
      "final Gaussians per seed")
for (tag, sc, v), d in sorted(rows.items()):
    seeds = sorted(d)
    ps = [float(d[s][4]) for s in seeds]
    base = [BASE[(sc, v)][s] for s in seeds]
    sd = f"{S.stdev(ps):.3f}" if len(ps) > 1 else "-"
    gs = [d[s][d[s].index("gaussians") + 3] for s in seeds]
    print(f"{tag} {sc:6s} {v} | {' / '.join(f'{x:.4f}' for x in ps)} | {S.mean(ps):.3f} ± {sd} | "
          f"{S.mean(base):.3f} | {S.mean(ps) - S.mean(base):+.3f} | {S.mean(float(d[s][5]) for s in seeds):.4f} | "
          f"{' '.join(gs)}")
