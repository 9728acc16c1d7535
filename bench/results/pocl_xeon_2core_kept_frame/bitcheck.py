"""Run fixed fits with the view_warp term in the tree given as argv[1]; save the states to argv[2]."""
import sys, os
root, out = sys.argv[1], sys.argv[2]
sys.path.insert(0, root)
sys.path.insert(0, os.path.join(root, "tests"))
sys.path.insert(0, os.path.join(root, "bench"))
from dataclasses import replace
import numpy as np
import reings
assert reings.__file__.startswith(root), reings.__file__
from cases import dngaussian_fit_case
from reings.train import fit, with_iterations
from reings.config import preset

def small():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=12, view_warp_baseline=0.3),
                  densify=replace(cfg.densify, opacity_decay=0.99, opacity_decay_from=5))
    return scene, init, cfg

def bench_like():
    from bench_fit import surface_init
    scene = reings.make_procedural_scene(n_views=3, width=200, height=150)
    init = surface_init(scene, 3000, 3, np.random.default_rng(0))
    cfg = with_iterations(preset("dngaussian"), 60)
    cfg = replace(cfg, sh_degree=3, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=1, view_warp_baseline=0.3,
                                                   drop_gamma=0.2))
    return scene, init, cfg

res = {}
s, i, c = small()
cases = {"small": (s, i, c),
         "small_drop_shared": (s, i, replace(c, loss=replace(c.loss, drop_gamma=0.2, soft_depth_shared=True))),
         "bench_like": bench_like()}
for name, (scene, init, cfg) in cases.items():
    for engine in ("device", "host"):
        r = fit(scene, cfg, device="pocl", init=init, depth_targets=list(scene.depths), progress=False,
                log_every=5, engine=engine)
        st = r.state
        key = f"{name}/{engine}"
        for k in st.params:
            res[f"{key}/p/{k}"] = st.params[k]
            res[f"{key}/m/{k}"] = st.adam.exp_avg[k]
            res[f"{key}/v/{k}"] = st.adam.exp_avg_sq[k]
        for k in st.stats:
            res[f"{key}/s/{k}"] = st.stats[k]
        res[f"{key}/loss"] = np.array(r.history.loss, np.float64)
        res[f"{key}/vw"] = np.array(r.history.view_warp, np.float64)
        print(key, len(st), len(r.history.view_warp), r.history.loss[-1], flush=True)
np.savez(out, **res)
