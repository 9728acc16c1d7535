"""Session 43's GPU runs (calls 1-2, 7) against the default of then (2,1,1, session 41's digits):
python3 summarize.py > summary.txt"""
import statistics as S

BASE = {("fern", 3): [22.25798297290443, 22.300828554576345, 22.213419818920027],
        ("flower", 3): [21.385892520600855, 21.3335903860959, 21.238297538858795],
        ("room", 3): [21.819226790583983, 21.79830277990556, 22.249035458618863]}
rows = {}
for f in ("call1_runs.txt", "call2_runs.txt", "call7_runs.txt"):
    for line in open(f):
        p = line.split()
        rows.setdefault((p[0], p[1], int(p[2])), {})[int(p[3])] = p
print("tag scene views | PSNR per seed | mean ± sample sd | Δ mean vs 2,1,1 on the same seeds | SSIM mean | "
      "training s per seed | final Gaussians per seed | off-frame (off*, it*) or near (near*) drops per fit "
      "(coarse/fine/final), per seed")
for (tag, sc, v), d in sorted(rows.items()):
    seeds = sorted(d)
    ps = [float(d[s][4]) for s in seeds]
    ss = [float(d[s][5]) for s in seeds]
    base = [BASE[(sc, v)][s] for s in seeds]
    sd = f"{S.stdev(ps):.3f}" if len(ps) > 1 else "-"
    tr = [d[s][d[s].index("training") + 1] for s in seeds]
    gs = [d[s][d[s].index("total") + 4] for s in seeds]
    at = {s: max(i for i, w in enumerate(d[s]) if i > 5 and w in ("off", "near")) for s in seeds}  # the drops' marker
    off = ["/".join(d[s][at[s] + 1:at[s] + 4]) for s in seeds]
    print(f"{tag:5s} {sc:6s} {v} | {' / '.join(f'{x:.4f}' for x in ps)} | {S.mean(ps):.3f} ± {sd} | "
          f"{S.mean(ps) - S.mean(base):+.3f} | {S.mean(ss):.4f} | {' '.join(tr)} | {' '.join(gs)} | {' '.join(off)}")
