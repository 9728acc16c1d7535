"""Host time of a fine-fit step with every kernel launch stubbed (docs/results.md §34): bench_host's case
(504x378, 30k Gaussians, SH 1) with the fine fit's passes (the shared soft depth term, view_warp, DropGaussian 0.2,
no hard depth pass), on PoCL; ms per iteration, steady state. Usage: python stubbed_fine_step.py SRC_TREE ITERATIONS
(the tree's reings and bench/bench_fit.py are imported)."""
import sys
import time
from dataclasses import replace

src, its = sys.argv[1], int(sys.argv[2])
sys.path.insert(0, src + "/bench")
sys.path.insert(0, src)
import numpy as np  # noqa: E402

import reings  # noqa: E402
from bench_fit import surface_init  # noqa: E402
from reings.backends.opencl.harness import launches_stubbed  # noqa: E402
from reings.pipeline import soft_depth_recipe  # noqa: E402
from reings.train import fit  # noqa: E402

assert reings.__file__.startswith(src), reings.__file__
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))


def recipe(n):
    c = soft_depth_recipe(6000, 1, "llff")
    L = replace(c.loss, hard_depth=False, soft_depth=True, soft_depth_from=1, soft_depth_shared=True, drop_gamma=0.2,
                view_warp_weight=1.0, view_warp_from=1, view_warp_baseline=0.05)
    return replace(c, iterations=n, sh_degree=1, sh_degree_interval=1, loss=L,
                   densify=replace(c.densify, densify_from=n + 1, densify_until=n + 1),
                   optim=replace(c.optim, position_lr_start=0, position_lr_max_steps=n))


def run(n):
    return fit(scene, recipe(n), device="pocl", init=init, depth_targets=list(scene.depths), log_every=10,
               engine="device")


run(3)  # kernel builds
with launches_stubbed():
    h = run(its).history
print(f"{src}: stubbed fine step {(h.seconds[-1] - h.seconds[0]) / (h.iteration[-1] - h.iteration[0]) * 1e3:.3f} ms/it")
