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
    ("llff", {"view_warp_start": 0.25}, 1.0, None), ("llff", {"view_warp_start": 0.0}, 1.0, None),
    ("llff", {"view_warp_every": 3}, 1.0, None), ("dtu", {"view_warp_every": 2}, 1.0, 0.995)])
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
        assert r.loss.view_warp_every == kw.get("view_warp_every", 1)  # every iteration by default
    else:
        assert r.loss == base.loss


def test_view_warp_every_is_recorded_only_off_its_default():
    """run_settings (what a resume and `reings eval` compare) holds view_warp_every only where it is not
    1, the value before the option existed (older folders resume); a bad value is refused."""
    from reings.pipeline import run_settings

    assert "view_warp_every" not in run_settings(RunConfig().resolved(), "llff")
    assert "view_warp_every" not in run_settings(RunConfig(view_warp_every=1).resolved(), "llff")
    assert run_settings(RunConfig(view_warp_every=2).resolved(), "llff")["view_warp_every"] == 2
    for bad in (0, -1, 1.5):
        with pytest.raises(ValueError, match="view_warp_every"):
            RunConfig(view_warp_every=bad).resolved()


def test_eval_and_tables_tell_view_warp_every_apart(tmp_path):
    """`reings eval` notices a finished run of another view_warp_every (absent = 1, the value before the
    option existed), and `reings table` keeps such runs in a cell of their own."""
    import json

    from reings.evaluate import _setting_tag, _settings_differ
    from reings.pipeline import run_settings

    one, two = RunConfig(), RunConfig(view_warp_every=2)
    for name, cfg in (("one", one), ("two", two)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(json.dumps({"config": run_settings(cfg.resolved(), "llff")}))
    assert "view_warp_every" in _settings_differ(str(tmp_path / "two" / "metrics.json"), one, "llff")
    assert "view_warp_every" in _settings_differ(str(tmp_path / "one" / "metrics.json"), two, "llff")
    assert _settings_differ(str(tmp_path / "two" / "metrics.json"), two, "llff") == ""
    tags = [_setting_tag({"method": "reings", "config": run_settings(c.resolved(), "llff")}) for c in (one, two)]
    assert tags[0] != tags[1] and "every 2" in tags[1]


@pytest.mark.parametrize("method", ["reings", "dngaussian"])
def test_run_recipe_per_method(method):
    """The binocular terms reach the reings fits only; the DTU background rules every fit."""
    ctx, _ = _ctx("dtu", method=method, seed=3, dtu_background=True)
    r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, "dtu"))
    assert r.seed == 3 and r.loss.dark_background and r.densify.dark_white_rules
    assert (r.loss.view_warp_weight, r.densify.opacity_decay) == ((1.0, 0.995) if method == "reings" else (0.0, None))
    off = _ctx("dtu", method=method)[0].run_recipe(baseline_recipe("dngaussian", 600, 0, "dtu"))
    assert not off.loss.dark_background and not off.densify.dark_white_rules


@pytest.mark.parametrize("family, given, want", [("llff", None, 0.2), ("dtu", None, 0.6), ("llff", 0.4, 0.4),
                                                  ("dtu", 0.3, 0.3), ("llff", 0.0, 0.0)])
@pytest.mark.parametrize("method", ["reings", "dngaussian"])
def test_lambda_dssim_reaches_every_fit(family, given, want, method):
    """--lambda-dssim: none leaves the recipe family's SSIM weight (DNGaussian's 0.2 / 0.6); a value given,
    0 included, reaches every fit, and is a resume key only when given."""
    from reings.pipeline import run_settings

    ctx, _ = _ctx(family, method=method, lambda_dssim=given)
    r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family))
    assert r.loss.lambda_dssim == want
    assert run_settings(ctx.cfg, family).get("lambda_dssim") == given


def test_lambda_dssim_of_the_3dgs_baseline():
    """The 3dgs baseline's loss is (1 - l) L1 + l (1 - SSIM): --lambda-dssim reaches it, and a weight above 1
    (a negative L1 weight) is refused; DNGaussian's form L1 + l (1 - SSIM) takes any l in [0, 10]."""
    from reings.backends.reference_loss import photometric_weights

    ctx, _ = _ctx("llff", method="3dgs", lambda_dssim=0.5)
    r = ctx.run_recipe(baseline_recipe("3dgs", 600, 0, "llff"))
    assert photometric_weights(r.loss.lambda_dssim, r.loss.photometric_form) == (0.5, 0.5)
    for bad in (1.5, 10.0):
        with pytest.raises(ValueError, match="lambda_dssim.*3dgs"):
            RunConfig(method="3dgs", lambda_dssim=bad)
    assert RunConfig(method="3dgs", lambda_dssim=1.0).lambda_dssim == (1.0,)
    assert RunConfig(method="dngaussian", lambda_dssim=2.0).lambda_dssim == (2.0,)
    with pytest.raises(ValueError, match="lambda_dssim.*3dgs"):  # its single fit takes the last of three
        RunConfig(method="3dgs", lambda_dssim=(0.2, 0.2, 1.5))


@pytest.mark.parametrize("method", ["reings", "dngaussian"])
def test_lambda_dssim_per_stage(method):
    """--lambda-dssim A,B,C: each reings fitting stage takes its own weight (coarse, fine, final); the
    baselines' single fit takes the last; the resume key is the list of the weights the fits use, a
    number when they are one."""
    from reings.config import parse_lambda_dssim
    from reings.pipeline import run_settings

    assert parse_lambda_dssim("0.2, 0.2,0.4") == (0.2, 0.2, 0.4)
    assert parse_lambda_dssim("0.3") == (0.3,)
    for bad, why in (("0.2,0.4", "one SSIM weight per reings stage"), ("0.2,x,0.4", "expected a number"),
                     ("0.2,0.2,11", r"\[0, 10\]"), ("nan", r"\[0, 10\]")):
        with pytest.raises(ValueError, match=why):
            parse_lambda_dssim(bad)
    with pytest.raises(ValueError, match="one weight or three"):
        RunConfig(lambda_dssim=(0.2, 0.4))
    ctx, _ = _ctx("llff", method=method, lambda_dssim=(0.1, 0.2, 0.4))
    got = {st: ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, "llff"), st).loss.lambda_dssim
           for st in ("coarse", "fine", "final", method)}
    assert got == {"coarse": 0.1, "fine": 0.2, "final": 0.4, method: 0.4}
    want = [0.1, 0.2, 0.4] if method == "reings" else 0.4
    assert run_settings(ctx.cfg, "llff")["lambda_dssim"] == want
    same, _ = _ctx("llff", method=method, lambda_dssim=(0.3, 0.3, 0.3))
    assert run_settings(same.cfg, "llff")["lambda_dssim"] == 0.3


@pytest.mark.parametrize("family, recipe_threshold", [("llff", 0.0013), ("dtu", 0.001)])
def test_grad_threshold_scale(family, recipe_threshold):
    """--grad-threshold-scale multiplies the recipe family's densification threshold (DNGaussian's
    0.0013 / 0.001) in every fit; 1 leaves it and is no resume key; bad values are refused."""
    from reings.pipeline import run_settings

    for scale in (1.0, 1.5, 0.5):
        ctx, _ = _ctx(family, grad_threshold_scale=scale)
        r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family), "fine")
        assert abs(r.densify.grad_threshold - recipe_threshold * scale) < 1e-15
        assert run_settings(ctx.cfg, family).get("grad_threshold_scale") == (None if scale == 1 else scale)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="grad_threshold_scale"):
            RunConfig(grad_threshold_scale=bad)


def test_eval_flags_other_ssim_weights_and_soft_depth_sharing(tmp_path):
    """`reings eval` does not take a finished run for the config's when the SSIM weight differs (given on
    either side: the key is absent at none), nor a paper-preset 'llff' run finished before its reings fits
    shared the soft depth render (the key is absent when off); the same settings are not flagged."""
    import json

    from reings.evaluate import _settings_differ
    from reings.pipeline import run_settings

    for name, run_cfg, grid_cfg, kind, key in (
            ("ssim_run", RunConfig(lambda_dssim=0.3), RunConfig(), "llff", "lambda_dssim"),
            ("ssim_grid", RunConfig(), RunConfig(lambda_dssim=0.3), "dtu", "lambda_dssim"),
            ("soft", RunConfig(preset="paper", soft_depth_shared=False), RunConfig(preset="paper"), "llff",
             "soft_depth_shared")):
        p = tmp_path / name / "metrics.json"
        p.parent.mkdir()
        p.write_text(json.dumps({"config": run_settings(run_cfg.resolved(), kind)}))
        assert key in _settings_differ(str(p), grid_cfg, kind), name
        assert _settings_differ(str(p), run_cfg, kind) == "", name
    p = tmp_path / "dtu_paper.json"  # since session 18 DTU's paper runs share it too: an older run is flagged
    p.write_text(json.dumps({"config": run_settings(RunConfig(preset="paper", soft_depth_shared=False).resolved(),
                                                    "dtu")}))
    assert "soft_depth_shared" in _settings_differ(str(p), RunConfig(preset="paper"), "dtu")
    p.write_text(json.dumps({"config": run_settings(RunConfig(preset="quick").resolved(), "dtu")}))
    assert _settings_differ(str(p), RunConfig(preset="quick", soft_depth_shared=False), "dtu") == ""  # quick: own pass
    p = tmp_path / "nop.json"  # an LLFF run without a prior from before the no-prior SSIM weights is flagged
    p.write_text(json.dumps({"config": run_settings(RunConfig(preset="paper", depth_prior="none",
                                                              lambda_dssim=0.2).resolved(), "llff")}))
    assert "lambda_dssim" in _settings_differ(str(p), RunConfig(preset="paper", depth_prior="none"), "llff")
# }}}


@pytest.mark.parametrize("family", ["llff", "dtu"])
@pytest.mark.parametrize("prior", ["none", "off", "stereo", "exact"])
def test_no_prior_rules(family, prior):
    """Without a depth prior the 'llff' family's reings fits take NO_PRIOR_BY_FAMILY's rules (the
    view_warp term from 1/3 of each fit, DropGaussian 0.3, the SSIM weight 0.2 / 0.4 / 0.4 in the coarse /
    fine / final fits); with a prior, on 'dtu' and for the baselines the family's rules stay (2/3; 0.2 for
    reings, 0 for dngaussian; the recipe's SSIM weight); a value given wins."""
    from reings.pipeline import (NO_PRIOR_BY_FAMILY, drop_gamma_of, fit_scale_of, lambda_dssim_of, run_settings,
                                 view_warp_start_of)

    assert NO_PRIOR_BY_FAMILY == {"llff": {"cross_warp": 0.15, "drop_gamma": 0.3, "view_warp_start": 1 / 3,
                                           "lambda_dssim": (0.2, 0.4, 0.4), "fit_scale": (1, 1, 1)}, "dtu": {}}
    rule = family == "llff" and prior in ("none", "off")
    ctx, _ = _ctx(family, depth_prior=prior)
    assert fit_scale_of(ctx.cfg, family, "coarse") == (2 if family == "llff" and not rule else 1)
    assert view_warp_start_of(ctx.cfg, family) == (1 / 3 if rule else 2 / 3)
    assert drop_gamma_of(ctx.cfg, family) == (0.3 if rule else 0.2)
    r = ctx.binocular(soft_depth_recipe(600, 0, family))
    assert r.loss.view_warp_from == (200 if rule else 400)
    s = run_settings(ctx.cfg, family)
    assert s.get("view_warp_start") == (1 / 3 if rule else None)  # recorded only off the old default
    assert s["drop_gamma"] == (0.3 if rule else 0.2)
    base, _ = _ctx(family, depth_prior=prior, method="dngaussian")
    assert drop_gamma_of(base.cfg, family) == 0.0
    given, _ = _ctx(family, depth_prior=prior, view_warp_start=0.5, drop_gamma=0.1)
    assert view_warp_start_of(given.cfg, family) == 0.5 and drop_gamma_of(given.cfg, family) == 0.1
    assert given.binocular(soft_depth_recipe(600, 0, family)).loss.view_warp_from == 300
    recipe_w = 0.2 if family == "llff" else 0.6  # DNGaussian's (docs/method.md §2.2)
    want = {"coarse": 0.2, "fine": 0.4, "final": 0.4} if rule else dict.fromkeys(("coarse", "fine", "final"), recipe_w)
    got = {st: ctx.run_recipe(soft_depth_recipe(600, 0, family), st).loss.lambda_dssim for st in want}
    assert got == want
    assert s.get("lambda_dssim") == ([0.2, 0.4, 0.4] if rule else None)
    assert lambda_dssim_of(base.cfg, family, "dngaussian") is None  # the baselines keep their recipe's
    assert base.run_recipe(soft_depth_recipe(600, 0, family), "dngaussian").loss.lambda_dssim == recipe_w
    given, _ = _ctx(family, depth_prior=prior, lambda_dssim=0.3)
    assert {st: lambda_dssim_of(given.cfg, family, st) for st in want} == dict.fromkeys(want, 0.3)


def test_no_prior_folders_of_before_are_not_taken_for_the_new_rules(tmp_path):
    """A no-prior LLFF run of before the rules (cross_warp 0.1, view_warp from 2/3, drop 0.2) is not
    resumed (checkpoints/run.json) and is flagged by `reings eval`, also when only the start differs
    (the other two given as before: view_warp_start is absent at 2/3); a stereo-prior run of before
    is still the same run."""
    import json

    from reings.evaluate import _settings_differ
    from reings.outputs import check_out
    from reings.pipeline import run_settings

    old_cfg = RunConfig(depth_prior="none", cross_warp=0.1, drop_gamma=0.2, view_warp_start=2 / 3)
    old = json.loads(json.dumps(run_settings(old_cfg.resolved(), "llff")))
    assert "view_warp_start" not in old and old["cross_warp"] == 0.1 and old["drop_gamma"] == 0.2
    for name, cfg, diff in (("default", RunConfig(depth_prior="none"), {"cross_warp", "drop_gamma", "view_warp_start"}),
                            ("given", RunConfig(depth_prior="none", cross_warp=0.1, drop_gamma=0.2), {"view_warp_start"})):
        out = tmp_path / name
        (out / "checkpoints").mkdir(parents=True)
        (out / "checkpoints" / "run.json").write_text(json.dumps(old))
        with pytest.raises(ValueError, match="other settings"):
            check_out(str(out), run_settings(cfg.resolved(), "llff"), False)
        (out / "metrics.json").write_text(json.dumps({"config": old}))
        got = _settings_differ(str(out / "metrics.json"), cfg, "llff")
        assert {part.split(" ", 1)[0] for part in got.split(", ")} == diff, got
    prior = json.loads(json.dumps(run_settings(RunConfig().resolved(), "llff")))
    assert "view_warp_start" not in prior and prior["drop_gamma"] == 0.2
    (tmp_path / "prior.json").write_text(json.dumps({"config": prior}))
    assert _settings_differ(str(tmp_path / "prior.json"), RunConfig(), "llff") == ""


def test_a_no_prior_run_records_the_rules(device):
    """reings.run (the keyword path) without a prior: the fits take the view_warp term from 1/3 and
    DropGaussian 0.3, and metrics.json records both (config.view_warp_start, drop_gamma) and the
    cross_warp default; with a prior (exact, on the procedural scene) the old rules."""
    import reings

    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, iterations=(6, 6, 6), device=device, with_lpips=False, eval_every=0, quiet=True,
              views=3, extent="frusta")
    for prior, start, frm, drop, cross in (("none", 1 / 3, 2, 0.3, 0.15), ("exact", None, 4, 0.2, None)):
        m = reings.run(method="reings", depth_prior=prior, **kw).metrics
        assert m["config"].get("view_warp_start") == start and m["run_config"]["view_warp_start"] is None, prior
        assert m["drop_gamma"] == drop and m["config"]["drop_gamma"] == drop, prior
        assert m.get("cross_warp") == cross and m["config"].get("cross_warp") == cross, prior
        fits = [s for s in m["stages"] if "config" in s]
        assert len(fits) == 3, prior
        assert [s["config"]["loss"]["view_warp_from"] for s in fits] == [frm] * 3, prior
        assert [s["config"]["loss"]["drop_gamma"] for s in fits] == [drop] * 3, prior


@pytest.mark.parametrize("kw, want", [(dict(lambda_dssim=(0.1, 0.2, 0.3)), [0.1, 0.2, 0.3]),
                                      (dict(depth_prior="none"), [0.2, 0.4, 0.4]),  # the no-prior rule
                                      (dict(depth_prior="exact"), [0.2, 0.2, 0.2])])  # the recipe's
def test_each_reings_fit_takes_its_stage_weight(monkeypatch, kw, want):
    """A whole reings run hands each fitting stage its own SSIM weight (RunContext.fit passes the
    stage's name to run_recipe): coarse, fine, final in order."""
    import reings

    got = []
    import reings.pipeline as P

    fit = P.fit

    def spy_fit(*a, **k):
        got.append((k.get("desc"), a[1].loss.lambda_dssim))
        return fit(*a, **k)

    monkeypatch.setattr("reings.pipeline.fit", spy_fit)
    reings.run(method="reings", iterations=2, quiet=True, with_lpips=False, eval_every=0, **kw)
    assert got == list(zip(("coarse", "fine", "final"), want))
