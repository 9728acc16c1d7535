"""Device memory of a fit with the view_warp term from iteration 1 at LLFF size (504x378, 50k
Gaussians SH3), in the tree argv[1]: DeviceBytes peak (every cl.Buffer), the backend scratch's
peak, and (new tree) the kept slot's buffers."""
import sys, os
root = sys.argv[1]
sys.path.insert(0, root); sys.path.insert(0, os.path.join(root, "bench"))
from dataclasses import replace
import numpy as np
import reings
assert reings.__file__.startswith(root)
from bench_fit import surface_init
from reings.backends import get_backend
from reings.backends.opencl.harness import DeviceBytes
from reings.config import preset
from reings.train import fit, with_iterations

scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 50_000, 3, np.random.default_rng(0))
its = int(sys.argv[2]) if len(sys.argv) > 2 else 6
cfg = with_iterations(preset("dngaussian"), its)
cfg = replace(cfg, sh_degree=3, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=1))
with DeviceBytes() as mem:
    be = get_backend("pocl")
    r = fit(scene, cfg, device="pocl", init=init, depth_targets=list(scene.depths), progress=False, log_every=its)
    print(f"N {len(init)} -> {len(r.gaussians)}; last stats {be.last_stats}")
    print(f"DeviceBytes: peak {mem.peak_bytes / 2**20:.2f} MiB over the fit")
print(f"backend scratch: peak {be.scratch.peak_bytes / 2**20:.2f} MiB, now {be.scratch.nbytes() / 2**20:.2f} MiB")
slots = getattr(be, "_slots", None)
if slots and len(slots) > 1:
    kept = {k: b.size for k, (b, _) in be.scratch._bufs.items() if k[1].endswith("@kept")}
    sl = slots[1]
    sorters = sum(s.buf.size for so in (sl.depth_sorter, sl.tile_sorter)
                  for s in (so._keys_tmp, so._vals_tmp, so._hist, so._totals) if s.buf is not None)
    tot = sum(kept.values()) + sorters
    print(f"kept slot: scratch {sum(kept.values()) / 2**20:.2f} MiB + its sorters {sorters / 2**20:.2f} MiB = {tot / 2**20:.2f} MiB")
    for space in ("gauss", "isect", "pixel", "tile", "small"):
        items = sorted(((n, b) for (sp, n), b in kept.items() if sp == space), key=lambda x: -x[1])
        print(f"  {space}: {sum(b for _, b in items) / 2**20:.2f} MiB  " + ", ".join(f"{n[:-5]} {b / 2**20:.2f}" for n, b in items))
    s0 = {k: b.size for k, (b, _) in be.scratch._bufs.items() if not k[1].endswith("@kept")}
    print(f"the rest of the scratch: {sum(s0.values()) / 2**20:.2f} MiB")
