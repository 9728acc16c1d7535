"""Final state and history of short fits whose densification does every row edit (clones, split
children, prunes by opacity and size, the opacity reset, DTU's black / white rules, the prune of
unseen Gaussians), on both engines, for a before / after bit comparison of the device surgery
(Trainer.apply_rows). Usage: python bitcheck.py SRC_TREE OUT.npz"""
import sys

src, out = sys.argv[1], sys.argv[2]
sys.path.insert(0, src + "/bench")
sys.path.insert(0, src)
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

import reings  # noqa: E402
from bench_fit import surface_init  # noqa: E402
from reings.config import preset  # noqa: E402
from reings.train import fit, with_iterations  # noqa: E402

assert reings.__file__.startswith(src), reings.__file__
scene = reings.make_procedural_scene(n_views=3, width=120, height=90)
init = surface_init(scene, 3000, 1, np.random.default_rng(0))
arrays = {}
cases = {
    # 3DGS / DNGaussian densification with size pruning and two opacity resets in the window
    "dng": lambda c: replace(c, densify=replace(c.densify, opacity_reset_interval=30, size_prune_from=20,
                                                 max_screen_size=40.0, max_world_size=2.0)),
    # a third of the initial points behind the cameras (kept by clean_views off): pruned as unseen
    "unseen": lambda c: replace(c, loss=replace(c.loss, drop_gamma=0.2),
                                densify=replace(c.densify, prune_unseen=True, clean_views=False)),
    "dtu": lambda c: replace(c, loss=replace(c.loss, dark_background=True),
                             densify=replace(c.densify, dark_white_rules=True, max_gaussians=4000)),
}
behind = replace(init, means=np.where((np.arange(len(init)) % 3 == 0)[:, None],
                                      init.means * [1, 1, -1] - [0, 0, 30], init.means).astype(np.float32))
for name, f in cases.items():
    cfg = f(replace(with_iterations(preset("dngaussian"), 90), sh_degree=1))
    for engine in ("device", "host"):
        r = fit(scene, cfg, device="pocl", init=behind if name == "unseen" else init, depth_targets=list(scene.depths), log_every=7, engine=engine)
        for k, v in r.state.to_arrays().items():
            arrays[f"{name}_{engine}_{k}"] = v
        h = r.history
        arrays[f"{name}_{engine}_loss"] = np.array(h.loss)
        arrays[f"{name}_{engine}_n"] = np.array(h.n_gaussians)
        arrays[f"{name}_{engine}_densify"] = np.array(repr(h.densify))
        print(name, engine, len(r.gaussians), "densify", h.densify, "loss", h.loss[-1], flush=True)
np.savez(out, **arrays)
