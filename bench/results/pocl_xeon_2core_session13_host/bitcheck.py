"""Final state + history of short fits (densification, prune_unseen, depth_metric, soft_depth_shared,
view_warp, drop) for a before/after bit comparison."""
import sys
src, out = sys.argv[1], sys.argv[2]
sys.path.insert(0, src + '/bench'); sys.path.insert(0, src)
from dataclasses import replace
import numpy as np, reings
from bench_fit import surface_init
from reings.config import preset
from reings.train import fit, with_iterations
scene = reings.make_procedural_scene(n_views=3, width=120, height=90)
init = surface_init(scene, 3000, 1, np.random.default_rng(0))
arrays = {}
cases = {
  "dng_densify": lambda c: c,
  "reings_like": lambda c: replace(c, loss=replace(c.loss, view_warp_weight=1.0, view_warp_from=10, view_warp_baseline=0.05,
                                                    drop_gamma=0.2, depth_metric=0.3),
                                   densify=replace(c.densify, prune_unseen=True)),
  "shared": lambda c: replace(c, loss=replace(c.loss, soft_depth_shared=True, soft_depth_from=5)),
}
for name, f in cases.items():
    cfg = f(replace(with_iterations(preset("dngaussian"), 60), sh_degree=1))
    for engine in ("device", "host"):
        r = fit(scene, cfg, device="pocl", init=init, depth_targets=list(scene.depths), log_every=7, engine=engine)
        for k, v in r.state.to_arrays().items():
            arrays[f"{name}_{engine}_{k}"] = v
        h = r.history
        arrays[f"{name}_{engine}_loss"] = np.array(h.loss); arrays[f"{name}_{engine}_psnr"] = np.array(h.train_psnr)
        arrays[f"{name}_{engine}_vw"] = np.array([x[1] for x in h.view_warp]); arrays[f"{name}_{engine}_dm"] = np.array([x[1] for x in h.depth_metric])
        print(name, engine, len(r.gaussians), "dens", len(h.densify), "loss", h.loss[-1], "psnr", h.train_psnr[-1], flush=True)
np.savez(out, **arrays)
