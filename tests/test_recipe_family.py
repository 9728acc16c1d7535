"""The recipe family of a run's fits (RunConfig.recipe, pipeline.recipe_family): DTU scenes train
with DNGaussian's DTU recipe (docs/method.md §2.2, right column), everything else with the LLFF one.

The expected values below are typed from docs/method.md §2.2, not read from reings.config, so a
preset that drifts from the documented recipe fails here."""
from __future__ import annotations

from dataclasses import replace

import pytest

from reings.config import RunConfig
from reings.pipeline import baseline_recipe, coarse_recipe, recipe_family, soft_depth_recipe


@pytest.mark.parametrize("kind, want", [("dtu", "dtu"), ("llff", "llff"), ("llff_nex", "llff"),
                                        ("colmap", "llff"), ("blender", "llff"), ("procedural", "llff")])
def test_auto_follows_the_dataset_kind(kind, want):
    assert recipe_family("auto", kind) == want


@pytest.mark.parametrize("forced", ["llff", "dtu"])
def test_forced_family_wins(forced):
    assert recipe_family(forced, "dtu") == forced
    assert recipe_family(forced, "llff") == forced


def test_dtu_recipe_values():
    """DNGaussian's DTU column (6000 iterations, so nothing is squeezed)."""
    c = baseline_recipe("dngaussian", 6000, 3, "dtu")
    o, L, d = c.optim, c.loss, c.densify
    assert (o.position_lr_init, o.position_lr_final) == (0.0016, 0.000016)
    assert (o.position_lr_start, o.position_lr_max_steps) == (500, 5500)
    assert (o.opacity_lr, o.scaling_lr, o.rotation_lr) == (0.05, 0.003, 0.001)
    assert (L.photometric_form, L.lambda_dssim) == ("dngaussian", 0.6)
    assert tuple(L.depth_patch_range) == (17, 53) and L.depth_margin == 0.01
    assert (L.shape_pena, L.scale_pena, L.opa_pena) == (0.005, 0.005, 0.001)
    assert L.soft_depth_ema_gate == 0.1 and L.depth_smooth_weight == 0.0
    assert L.hard_depth and L.soft_depth and L.soft_depth_from == 1001
    assert (d.grad_threshold, d.percent_dense, d.split_opacity_thresh, d.prune_opacity) == (0.001, 0.1, 0.1, 0.01)
    assert (d.densify_from, d.densify_until, d.densify_interval) == (500, 6000, 100)
    assert d.opacity_reset_interval is None and d.clean_views


def test_llff_default_is_unchanged():
    for its in (600, 6000):
        assert baseline_recipe("dngaussian", its, 1) == baseline_recipe("dngaussian", its, 1, "llff")
        assert soft_depth_recipe(its, 1) == soft_depth_recipe(its, 1, "llff")
        assert coarse_recipe(its, 1, 0.99) == coarse_recipe(its, 1, 0.99, "llff")
    assert baseline_recipe("dngaussian", 6000, 3).loss.lambda_dssim == 0.2


def test_reings_dtu_stages():
    """coarse: hard depth only; fine/final: soft depth only, and ungated (there is no hard loss in
    those fits for the DTU recipe's EMA gate to read, so a gate would switch the term off)."""
    c = coarse_recipe(6000, 1, 0.99, "dtu")
    assert c.loss.hard_depth and not c.loss.soft_depth and c.loss.hard_depth_opacity == 0.99
    assert c.loss.lambda_dssim == 0.6
    f = soft_depth_recipe(6000, 1, "dtu")
    assert f.loss.soft_depth and not f.loss.hard_depth and f.loss.soft_depth_ema_gate is None
    assert f.loss.lambda_dssim == 0.6 and not f.densify.clean_views


def test_soft_depth_runs_in_the_dtu_fine_fit():
    """The fine recipe's soft-depth pass really runs (profile phase present) on a tiny scene."""
    from cases import dngaussian_fit_case
    from reings.train import fit

    scene, init, _ = dngaussian_fit_case(2, 40, 30, 200, 0, 8, 1, 1)
    cfg = soft_depth_recipe(8, 0, "dtu")
    cfg = replace(cfg, loss=replace(cfg.loss, soft_depth_from=2, depth_patch_range=(5, 9)))
    prof: dict = {}
    fit(scene, cfg, device="reference", init=init, depth_targets=list(scene.depths), progress=False, profile=prof)
    assert prof.get("soft_render", 0) > 0
    assert "hard_render" not in prof


def test_recipe_option():
    assert RunConfig(recipe="dtu").recipe == "dtu"
    with pytest.raises(ValueError, match="recipe"):
        RunConfig(recipe="blender")


# {{{ the view_warp term and the opacity decay of the reings fits (RunContext.binocular)

def _ctx(family: str, **kw):
    import numpy as np

    import reings
    from reings.data.sfm import SfmExtent
    from reings.pipeline import RunContext

    scene = reings.make_procedural_scene(n_views=3, width=32, height=24, supersample=1)
    cam = scene.cameras[0]
    # points straight ahead of camera 0 at depths 2, 4, 6: its median is 4
    pts = np.array([cam.center + z * cam.viewmat[2, :3] for z in (2.0, 4.0, 6.0)])
    box = SfmExtent(pts.min(0), pts.max(0), "sfm", pts, np.zeros((3, 3), np.float32))
    cfg = RunConfig(**kw).resolved()
    return RunContext(cfg, None, scene.subset([0]), scene.subset([1]), None, box, print, False, family=family), cam


def test_typical_depth_is_the_median_point_depth():
    from reings.pipeline import typical_depth

    ctx, cam = _ctx("llff")
    assert abs(typical_depth([cam], ctx.box) - 4.0) < 1e-9


@pytest.mark.parametrize("family, kw, weight, decay", [
    ("llff", {}, 1.0, None), ("dtu", {}, 1.0, 0.995),                     # the defaults per family
    ("dtu", {"opacity_decay": 1.0}, 1.0, None), ("llff", {"opacity_decay": 0.99}, 1.0, 0.99),
    ("llff", {"view_warp": 0.0}, 0.0, None), ("llff", {"view_warp": 2.0, "view_warp_disparity": 8.0}, 2.0, None),
    ("llff", {"view_warp_start": 0.25}, 1.0, None), ("llff", {"view_warp_start": 0.0}, 1.0, None)])
def test_binocular_settings_of_the_reings_fits(family, kw, weight, decay):
    ctx, cam = _ctx(family, **kw)
    base = soft_depth_recipe(600, 0, family)
    r = ctx.binocular(base)
    assert r.loss.view_warp_weight == weight and r.densify.opacity_decay == decay
    if weight:
        px = kw.get("view_warp_disparity", 4.0)
        assert abs(r.loss.view_warp_baseline - px * 4.0 / cam.fx) < 1e-9  # px at the median depth 4
        start = kw.get("view_warp_start")
        assert r.loss.view_warp_from == (400 if start is None else max(1, round(start * 600)))  # 2/3 by default
    else:
        assert r.loss == base.loss


@pytest.mark.parametrize("method", ["reings", "dngaussian"])
def test_run_recipe_per_method(method):
    """The binocular terms reach the reings fits only; the DTU background rules every fit."""
    ctx, _ = _ctx("dtu", method=method, seed=3, dtu_background=True)
    r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, "dtu"))
    assert r.seed == 3 and r.loss.dark_background and r.densify.dark_white_rules
    assert (r.loss.view_warp_weight, r.densify.opacity_decay) == ((1.0, 0.995) if method == "reings" else (0.0, None))
    off = _ctx("dtu", method=method)[0].run_recipe(baseline_recipe("dngaussian", 600, 0, "dtu"))
    assert not off.loss.dark_background and not off.densify.dark_white_rules
# }}}
