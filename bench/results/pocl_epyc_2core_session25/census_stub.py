"""Kernel launches per iteration by kernel name, every launch stubbed (no kernel runs), on PoCL: bench_host's case
(504x378, 30k Gaussians, SH 1) with the fine fit's passes (shared soft depth, view_warp, DropGaussian 0.2) or the
coarse fit's (hard depth, view_warp, DropGaussian 0.2). docs/results.md §35.
Usage: python census_stub.py SRC_TREE ITERATIONS fine|coarse (the tree's reings and bench/bench_fit.py are imported)."""
import sys, collections
src, its, coarse = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "coarse"
sys.path.insert(0, src + "/bench"); sys.path.insert(0, src)
from dataclasses import replace
import numpy as np, reings
from bench_fit import surface_init
from reings.pipeline import soft_depth_recipe
from reings.train import fit
import pyopencl._cl as _cl
scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
init = surface_init(scene, 30000, 1, np.random.default_rng(0))
def recipe(n):
    c = soft_depth_recipe(6000, 1, "llff")
    if coarse:
        L = replace(c.loss, hard_depth=True, soft_depth=False, drop_gamma=0.2, view_warp_weight=1.0, view_warp_from=1, view_warp_baseline=0.05)
    else:
        L = replace(c.loss, hard_depth=False, soft_depth=True, soft_depth_from=1, soft_depth_shared=True, drop_gamma=0.2,
                view_warp_weight=1.0, view_warp_from=1, view_warp_baseline=0.05)
    return replace(c, iterations=n, sh_degree=1, sh_degree_interval=1, loss=L,
                   densify=replace(c.densify, densify_from=n + 1, densify_until=n + 1),
                   optim=replace(c.optim, position_lr_start=0, position_lr_max_steps=n))
def run(n):
    return fit(scene, recipe(n), device="pocl", init=init, depth_targets=list(scene.depths), log_every=10, engine="device")
run(3)
cnt = collections.Counter(); copies = collections.Counter()
orig = _cl.enqueue_nd_range_kernel
def f(q, k, *a, **kw):
    cnt[k.function_name] += 1
_cl.enqueue_nd_range_kernel = f
run(its)
_cl.enqueue_nd_range_kernel = orig
tot = sum(cnt.values())
print("launches/it", tot/its)
for k, v in cnt.most_common(): print(f"{k:32s} {v/its:6.2f}")
