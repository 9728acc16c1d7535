"""python summarize.py: session 41's fit_scale runs (callN_runs.txt here) against the defaults' digits (session 38's
H200 runs, bench/results/h100_session38/hd.txt, trex.txt, views2.txt; session 40's fast preset, the fast_600_600_2400
rows of bench/results/h100_session40/call2_runs.txt): per scene the seeds' PSNR, mean, sample sd and the difference of
the means; the SSIM means alike."""
import glob
import os
import statistics as st

HERE = os.path.dirname(os.path.abspath(__file__))
BASE = {("fern", 3): ([22.3598, 22.2314, 22.1712], [0.735, 0.7319, 0.7301]),
        ("flower", 3): ([21.1994, 21.1421, 21.5354], [0.6796, 0.6805, 0.6886]),
        ("room", 3): ([21.7432, 22.0574, 21.3225], [0.8371, 0.8406, 0.8308]),
        ("trex", 3): ([22.5522, 22.4928, 22.6417], [0.817, 0.818, 0.8212]),
        ("fern", 2): ([21.3326, 21.0397, 21.3330], [0.6899, 0.6807, 0.6904]),
        ("flower", 2): ([20.1362, 20.1385, 20.1711], [0.6322, 0.6337, 0.6302])}
FAST = {"fern": [22.5848, 22.5507, 22.4928], "flower": [21.0180, 21.0774, 21.2601], "room": [21.7747, 21.6460, 21.8711]}
rows = {}
for f in sorted(glob.glob(os.path.join(HERE, "call*_runs.txt"))):
    for line in open(f):
        p = line.split()
        if len(p) < 6:
            continue
        if p[2] in ("0", "1", "2") and "." in p[3]:  # call 1's rows carry no views column (3 views)
            tag, sc, v, seed, psnr, ssim = p[0], p[1], 3, int(p[2]), float(p[3]), float(p[4])
        else:
            tag, sc, v, seed, psnr, ssim = p[0], p[1], int(p[2]), int(p[3]), float(p[4]), float(p[5])
        rows[(tag, sc, v, seed)] = (psnr, ssim)
print("setting scene views | PSNR seeds 0/1/2 | mean sd | delta (paired seeds) | SSIM mean delta")
for tag in ("s221", "s211", "s411"):
    for (sc, v), (bp, bs) in BASE.items():
        got = [rows.get((tag, sc, v, s)) for s in range(3)]
        have = [s for s in range(3) if got[s] is not None]
        if not have:
            continue
        ps = [got[s][0] for s in have]
        ss = [got[s][1] for s in have]
        print(tag, sc, v, "|", " / ".join("%.4f" % got[s][0] if got[s] else "-" for s in range(3)), "|",
              "%.3f %.3f" % (st.mean(ps), st.stdev(ps) if len(ps) > 1 else 0.0), "|", "%+.3f (n=%d)" % (st.mean(ps) - st.mean(bp[s] for s in have), len(have)),
              "|", "%.4f %+.4f" % (st.mean(ss), st.mean(ss) - st.mean(bs[s] for s in have)))
for sc, b in FAST.items():
    ps = [rows[("fast211", sc, 3, s)][0] for s in range(3)]
    print("fast211", sc, 3, "|", " / ".join("%.4f" % x for x in ps), "|", "%.3f %.3f" % (st.mean(ps), st.stdev(ps) if len(ps) > 1 else 0.0), "|",
          "%+.3f (n=3)" % (st.mean(ps) - st.mean(b)))
