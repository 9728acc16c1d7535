"""Session 43's census (census_Avw2near.json) at session 41's census speed and at session 40's machine speed [estimate]:
    python3 bench/results/pocl_xeon_2core_session43/normalize.py > bench/results/pocl_xeon_2core_session43/normalize.txt
Each stage at session 41's census speed: its busy ms per iteration over the kernels' speed ratio (the identical coarse
fit's busy time, this run over session 41's) plus session 41's host gap per iteration of that stage; then session
41's census to session 40's speed with docs/results.md §52's per-stage factors (coarse 279.6 -> 236.3 s, fine / 1.27,
final / 1.10)."""
import json
import os

here = os.path.dirname(os.path.abspath(__file__))
a = json.load(open(os.path.join(here, "..", "pocl_xeon_2core_session41", "census_211.json")))["stages"]
b = json.load(open(os.path.join(here, "census_Avw2near.json")))["stages"]
k = b["coarse"]["busy_ms_per_it"] / a["coarse"]["busy_ms_per_it"]
print(f"kernels' speed ratio (the identical coarse fit's busy ms per iteration, this run / session 41's): {k:.3f}")
f40 = {"coarse": 236.3 / 279.6, "fine": 1 / 1.27, "final": 1 / 1.10}
tot = 0.0
for st in ("coarse", "fine", "final"):
    at41 = b[st]["iterations"] * (b[st]["busy_ms_per_it"] / k + a[st]["gap_ms_per_it"]) / 1000
    tot += at41 * f40[st]
    print(f"{st:6s} measured {b[st]['wall_s']:.1f} s (busy {b[st]['busy_ms_per_it']:.2f}, gaps {b[st]['gap_ms_per_it']:.2f} "
          f"ms/it); at session 41's census speed {at41:.1f} s; at session 40's speed {at41 * f40[st]:.1f} s")
print(f"training at session 40's machine speed: {tot:.1f} s [estimate]")
