"""python compare.py A.json B.json [stage ...]: two kernel censuses (bench/kernel_census.py) side by side per stage:
wall seconds, busy ms per iteration, and per kernel B's ms per iteration over A's (the untouched kernels' ratio is the
machine's speed between the two runs)."""
import json
import sys

a, b = (json.load(open(p))["stages"] for p in sys.argv[1:3])
for st in sys.argv[3:] or ("coarse", "fine", "final"):
    ka, kb = dict(a[st]["kernels"]), dict(b[st]["kernels"])
    print(f"{st}: wall {a[st]['wall_s']:.1f} -> {b[st]['wall_s']:.1f} s, busy {a[st]['busy_ms_per_it']:.2f} -> "
          f"{b[st]['busy_ms_per_it']:.2f} ms/it, gaps {a[st]['gap_ms_per_it']:.2f} -> {b[st]['gap_ms_per_it']:.2f}")
    for k in sorted(ka, key=lambda k: -ka[k]["ms_per_it"])[:24]:
        if k in kb and ka[k]["ms_per_it"] > 0.05:
            print(f"    {k:26s} {ka[k]['ms_per_it']:8.3f} -> {kb[k]['ms_per_it']:8.3f}  x{kb[k]['ms_per_it'] / ka[k]['ms_per_it']:.3f}"
                  f"  launches {ka[k]['launches_per_it']:.2f} -> {kb[k]['launches_per_it']:.2f}")
