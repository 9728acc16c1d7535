"""RunConfig.fit_scale: a reings fit on the training views at 1/S resolution (issue 15).

The views (`pipeline.scaled_views`): each image averaged over S x S blocks against a loop in float64,
the camera that of the hard pass at 1/S (`train.depth_pass_camera`, tested against the pinhole model
in tests/test_hard_depth_scale.py), the priors and confidences averaged likewise. Then the run: each
fitting stage gets its own scale (the coarse fit's views, targets and recipe at 1/2 under the LLFF
default; the fine and final fits' as before), the depth patch rule (LossConfig.depth_patch_div: each
drawn size divided by S, rounded up) reaches every depth loss call, the settings record the scales
(absent when all are 1, so older run folders resume), and `reings eval` / `reings table` tell runs of
other scales apart."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from reings.config import RunConfig, parse_fit_scale


def test_the_option_parses_and_refuses():
    assert parse_fit_scale("2,1,1") == (2, 1, 1) and parse_fit_scale("4") == (4,)
    for bad, why in (("3", "must be 1, 2 or 4, got 3"), ("2,2", "expected S or A,B,C"), ("0,1,1", "got 0"),
                     ("x", "expected an integer")):
        with pytest.raises(ValueError, match=why):
            parse_fit_scale(bad)
    with pytest.raises(ValueError, match="must be 1, 2 or 4, got 3"):
        RunConfig(fit_scale=(3,))
    with pytest.raises(ValueError, match="one scale or three"):
        RunConfig(fit_scale=(2, 1))
    from reings.cli import build_parser, config_from_args

    assert config_from_args(build_parser().parse_args(["run", "--fit-scale", "2,2,1"])).fit_scale == (2, 2, 1)


@pytest.mark.parametrize("method, family, kw, want", [
    ("reings", "llff", {}, (2, 1, 1)), ("reings", "dtu", {}, (1, 1, 1)),  # the family defaults
    ("reings", "llff", {"fit_scale": (1,)}, (1, 1, 1)), ("reings", "dtu", {"fit_scale": (2, 2, 1)}, (2, 2, 1)),
    ("reings", "llff", {"depth_prior": "none"}, (1, 1, 1)),  # without a prior: not measured, 1
    ("reings", "llff", {"depth_prior": "none", "fit_scale": (2, 1, 1)}, (2, 1, 1)),
    ("dngaussian", "llff", {"fit_scale": (2,)}, (1, 1, 1))])  # the baselines: always 1
def test_the_scale_of_each_stage(method, family, kw, want):
    from reings.pipeline import FIT_SCALE_BY_FAMILY, fit_scale_of

    assert FIT_SCALE_BY_FAMILY == {"llff": (2, 1, 1), "dtu": (1, 1, 1)}
    cfg = RunConfig(method=method, **kw).resolved()
    assert tuple(fit_scale_of(cfg, family, st) for st in ("coarse", "fine", "final")) == want
    assert fit_scale_of(cfg, family, None) == 1 and fit_scale_of(cfg, family, method) == 1


def test_scaled_views_against_a_loop():
    import reings
    from reings.pipeline import scaled_views
    from reings.train import depth_pass_camera

    scene = reings.make_procedural_scene(n_views=2, width=33, height=21, supersample=1)
    rng = np.random.default_rng(0)
    priors = [rng.random((21, 33)).astype(np.float32) * 5, None]
    assert scaled_views(scene, priors, None, 2)[2] is None
    conf = [None, rng.random((21, 33)).astype(np.float32)]
    views, p2, c2 = scaled_views(scene, priors, conf, 2)
    assert c2[0] is None and p2[1] is None and len(views) == 2
    ref = np.array([[np.mean(conf[1][2 * i:2 * i + 2, 2 * j:2 * j + 2].astype(np.float64)) for j in range(16)]
                    for i in range(10)])
    np.testing.assert_array_equal(c2[1], ref.astype(np.float32))
    for (im, cam), im0, cam0 in zip(views, scene.images, scene.cameras):
        ref = np.array([[[np.mean(im0[2 * i:2 * i + 2, 2 * j:2 * j + 2, c].astype(np.float64)) for c in range(3)]
                         for j in range(16)] for i in range(10)])
        assert im.dtype == np.float32 and im.shape == (10, 16, 3) and im.flags.c_contiguous
        np.testing.assert_array_equal(im, ref.astype(np.float32))
        small = depth_pass_camera(cam0, 2)
        assert (cam.width, cam.height) == (16, 10) and np.array_equal(cam.K, small.K)
        assert np.array_equal(cam.viewmat, cam0.viewmat)
    ref = np.array([[np.mean(priors[0][2 * i:2 * i + 2, 2 * j:2 * j + 2].astype(np.float64)) for j in range(16)]
                    for i in range(10)])
    np.testing.assert_array_equal(p2[0], ref.astype(np.float32))


def test_each_fit_takes_its_scale(monkeypatch):
    """A whole reings run (the procedural scene: the LLFF family, exact depths as the prior): the coarse fit
    gets the views, targets and recipe at 1/2 (its hard pass at 1 of the small views, the patches divided by
    2), the fine and final fits today's (the hard pass at 1/2 of the full views); the scales reach
    metrics.json's settings."""
    import reings
    import reings.pipeline as P

    got, fit = [], P.fit

    def spy_fit(views, recipe, **k):
        sizes = [(im.shape[0], im.shape[1]) for im in (views.images if hasattr(views, "images") else
                                                        [v[0] for v in views])]
        tgt = k.get("depth_targets")
        got.append((k.get("desc"), sizes, None if tgt is None else [t.shape for t in tgt],
                    recipe.loss.hard_depth_scale, recipe.loss.depth_patch_div))
        return fit(views, recipe, **k)

    monkeypatch.setattr("reings.pipeline.fit", spy_fit)
    r = reings.run(method="reings", iterations=2, quiet=True, with_lpips=False, eval_every=0)
    (c, cs, ct, ch, cd), (f, fs, ft, fh, fd), (z, zs, zt, zh, zd) = got
    assert (c, f, z) == ("coarse", "fine", "final")
    h, w = fs[0]
    assert cs == [(h // 2, w // 2)] * len(fs) and zs == fs
    assert ct == [(h // 2, w // 2)] * len(fs) and ft == zt == [(h, w)] * len(fs)
    assert (ch, cd) == (1, 2) and (fh, fd) == (zh, zd) == (2, 1)
    assert r.metrics["config"]["fit_scale"] == [2, 1, 1]


def test_the_patch_sizes_follow_the_divisor(device, monkeypatch):
    """LossConfig.depth_patch_div 2: every depth loss call (the hard pass at the views' own size, the soft term)
    gets each drawn size (drawn against twice the frame's size) halved, rounded up, within [2, the frame's size]."""
    from cases import dngaussian_fit_case

    from reings import losses
    from reings.backends.opencl.trainer import DeviceTrainer
    from reings.train import fit

    drawn, got = [], []
    draw, depth_loss = losses.draw_depth_patches, DeviceTrainer.depth_loss

    def spy_draw(rng, rg, h, w):
        drawn.append((draw(rng, rg, h, w), h, w))
        return drawn[-1][0]

    def spy_loss(self, fr, view, pl, pg, *a, **k):
        got.append((fr.height, fr.width, pl, pg))
        return depth_loss(self, fr, view, pl, pg, *a, **k)

    monkeypatch.setattr(losses, "draw_depth_patches", spy_draw)
    monkeypatch.setattr(DeviceTrainer, "depth_loss", spy_loss)
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=32, height=24, n_points=200, sh_degree=0, iterations=8,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, depth_patch_div=2, depth_patch_range=(1, 60)))
    fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False, engine="device")
    assert len(drawn) == len(got) == 8 + 6  # 8 hard, 6 soft
    odd = 0
    for ((pl, pg), dh, dw), (h, w, ql, qg) in zip(drawn, got):
        assert (dh, dw) == (2 * h, 2 * w)
        assert (ql, qg) == tuple(min(max(2, -(-p // 2)), h, w) for p in (pl, pg))
        odd += bool(pl % 2 or pg % 2) and 3 < min(pl, pg) < 2 * h
    assert odd  # an odd size was drawn: rounding up, not down, is checked
    assert min(q for *_, ql, qg in got for q in (ql, qg)) == 2 and max(q for *_, ql, qg in got for q in (ql, qg)) == 24


def test_settings_tag_and_reuse(tmp_path):
    """run_settings records the scales only when one is not 1 (older run folders resume); `reings eval` counts
    a finished run of other scales as not done; `reings table` keeps them in groups of their own."""
    from reings.evaluate import _setting_tag, _settings_differ
    from reings.pipeline import run_settings

    cfg = RunConfig()
    now = json.loads(json.dumps(run_settings(cfg.resolved(), "llff")))
    assert now["fit_scale"] == [2, 1, 1]
    assert "fit_scale" not in run_settings(RunConfig(fit_scale=(1,)).resolved(), "llff")
    assert "fit_scale" not in run_settings(cfg.resolved(), "dtu")
    runs = {"now": now, "old": {k: v for k, v in now.items() if k != "fit_scale"}, "other": {**now, "fit_scale": [2, 2, 1]}}
    for name, config in runs.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(json.dumps({"config": config}))
    assert _settings_differ(str(tmp_path / "now" / "metrics.json"), cfg, "llff") == ""
    assert "fit_scale" in _settings_differ(str(tmp_path / "old" / "metrics.json"), cfg, "llff")
    assert "fit_scale" in _settings_differ(str(tmp_path / "other" / "metrics.json"), cfg, "llff")
    tags = {name: _setting_tag({"method": "reings", "preset": "paper", "config": c}) for name, c in runs.items()}
    assert "scale 2/1/1" in tags["now"] and "scale" not in tags["old"] and "scale 2/2/1" in tags["other"]


@pytest.mark.parametrize("kw, want", [({}, (1, 1, 1)), ({"view_warp_scale": 2}, (1, 2, 2)),
                                      ({"view_warp_scale": 2, "fit_scale": (1,)}, (2, 2, 2)),
                                      ({"view_warp_scale": 2, "fit_scale": (2,)}, (1, 1, 1))])
def test_the_view_warp_scale_is_over_the_fits_own(kw, want):
    """RunConfig.view_warp_scale S: each reings fit's term at 1/max(1, S // F) of its views (F its fit scale: the
    LLFF default's coarse fit at 1/2 keeps the term at its own resolution); recorded in the settings (absent at 1)
    and in `reings table`'s tag."""
    from test_recipe_family import _ctx

    from reings.evaluate import _setting_tag
    from reings.pipeline import run_settings, soft_depth_recipe

    ctx, _ = _ctx("llff", **kw)
    assert ctx.cfg.view_warp  # the term is on by default
    got = tuple(ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), st).loss.view_warp_scale
                for st in ("coarse", "fine", "final"))
    assert got == want
    s = run_settings(ctx.cfg, "llff")
    assert s.get("view_warp_scale") == kw.get("view_warp_scale")
    tag = _setting_tag({"method": "reings", "preset": "paper", "config": json.loads(json.dumps(s))})
    assert ("at 1/2" in tag) == ("view_warp_scale" in kw)


def test_notes_and_refusals_of_the_two_scales():
    """A scale given where nothing takes it gets a note (not a silent drop); a view too small for the fit's
    blocks is refused with the option's name."""
    import reings
    from reings.pipeline import option_notes, scaled_views

    def notes(**kw):
        return option_notes(RunConfig(**kw).resolved(), "llff", 3)

    assert any("fit_scale" in n for n in notes(method="dngaussian", fit_scale=(2,)))
    assert not any("fit_scale" in n for n in notes(method="dngaussian", fit_scale=(1,)) + notes(fit_scale=(2,)))
    assert any("view_warp_scale" in n for n in notes(view_warp_scale=2, view_warp=0.0))
    assert any("view_warp_scale" in n for n in notes(method="3dgs", view_warp_scale=2))
    assert not any("view_warp_scale" in n for n in notes(view_warp_scale=2))
    scene = reings.make_procedural_scene(n_views=1, width=3, height=1, supersample=1)
    with pytest.raises(ValueError, match="fit_scale 2: a 3x1 training view has no 2x2 block"):
        scaled_views(scene, None, None, 2)
