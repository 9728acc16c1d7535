"""Per fit: the untouched kernels' busy ms/it ratio (B / A) and the changed kernels' ms/it, two census JSONs."""
import json, sys
a, b = (json.load(open(p))["stages"] for p in sys.argv[1:3])
changed = {"isect_reduce", "tile_ranges", "regularize_opacity_count", "loss_row_sums", "ssim_vpass_fwd", "ssim_vpass_bwd", "ssim_hpass_fwd", "ssim_hpass_bwd"} if "--ssim" in sys.argv else {"isect_reduce", "tile_ranges", "regularize_opacity_count", "loss_row_sums"}
tot_a = tot_b = 0.0
for st in ("coarse", "fine", "final"):
    ka, kb = a[st]["kernels"], b[st]["kernels"]
    ua = sum(v["ms_per_it"] for k, v in ka.items() if k not in changed)
    ub = sum(kb[k]["ms_per_it"] for k in ka if k not in changed and k in kb)
    ca = sum(ka[k]["ms_per_it"] for k in changed if k in ka)
    cb = sum(kb[k]["ms_per_it"] for k in changed if k in kb)
    r = ub / ua
    its = a[st]["iterations"]
    print(f"{st:6s} wall {a[st]['wall_s']:7.1f} -> {b[st]['wall_s']:7.1f} s | untouched {ua:6.2f} -> {ub:6.2f} ms/it (x{r:.3f}) | "
          f"changed {ca:5.2f} -> {cb:5.2f} ms/it ({(cb - ca) * its / 1e3:+.1f} s) | gaps {a[st]['gap_ms_per_it']:.2f} -> {b[st]['gap_ms_per_it']:.2f}")
    # B's wall at A's host speed: B's busy with its untouched kernels scaled back by r, plus B's gaps
    bw = (ub / r + cb + b[st]["gap_ms_per_it"]) * its / 1e3
    tot_a += a[st]["wall_s"]; tot_b += bw
    print(f"       B at A's host speed (untouched / {r:.3f}): {bw:7.1f} s")
print(f"total wall A {tot_a:.1f} s; B at A's host speed {tot_b:.1f} s")
