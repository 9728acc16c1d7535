"""`--extent frusta`: the training-frusta box asked for directly, identical to the fallback box."""
import numpy as np
import pytest

import reings
from reings.data.sfm import frusta_extent, frusta_only_extent


def test_frusta_only_extent_is_the_fallback_box():
    scene = reings.make_procedural_scene()
    tr, _ = reings.few_shot_split(scene, 3)
    train = scene.subset(tr)
    ext = frusta_only_extent(train)
    lo, hi, _ = frusta_extent(train.cameras, train.bounds)
    assert ext.method == "frusta" and ext.note == "requested"
    np.testing.assert_array_equal(ext.lo, lo)
    np.testing.assert_array_equal(ext.hi, hi)
    assert np.all(ext.hi > ext.lo)


def test_run_records_the_extent_choice(device):
    r = reings.run(method="dngaussian", iterations=3, device=device, depth_prior="none", extent="frusta",
                   with_lpips=False, eval_every=0, quiet=True)
    assert r.metrics["sfm"]["method"] == "frusta"
    assert r.metrics["config"]["extent"] == "frusta"
    with pytest.raises(ValueError, match="extent"):
        reings.run(method="dngaussian", iterations=3, device=device, extent="box", quiet=True)


def test_stereo_box_spans_the_confident_points_of_the_exact_depths():
    """stereo_box with the exact depths and a confidence of 1 on the left half of each view: its
    points are those pixels back-projected, its box their 1-99 % range."""
    from reings.reinit import backproject_pixels, stereo_box

    scene = reings.make_procedural_scene(n_views=3, width=64, height=48, supersample=1)
    conf = np.zeros((48, 64), np.float32)
    conf[:, :32] = 1.0
    box = stereo_box(scene, scene.depths, [conf] * 3, 0.5)
    idx = np.flatnonzero(conf.ravel() >= 0.5)
    want = np.concatenate([backproject_pixels(c, idx, d.ravel()[idx].astype(np.float64))
                           for c, d in zip(scene.cameras, scene.depths)])
    assert box.method == "stereo"
    np.testing.assert_allclose(box.points, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(box.lo, np.quantile(want, 0.01, axis=0))
    np.testing.assert_allclose(box.hi, np.quantile(want, 0.99, axis=0))
    assert stereo_box(scene, scene.depths, [conf * 0.4] * 3, 0.5) is None  # nothing confident enough
    assert stereo_box(scene, [None] * 3, [None] * 3, 0.5) is None  # a prior without depth or confidence


def test_sfm_failure_falls_back_to_the_stereo_box_and_seeds_ehps(device, monkeypatch):
    """When SfM triangulates too few points, a run with the stereo prior takes its box from the
    prior's confident pixels and seeds EHPS from them (stereo_seeds none = auto); with
    stereo_seeds 0 EHPS has its own points only; --extent frusta keeps the frusta."""
    import reings.data.sfm as sfm

    def failed(train, **kw):
        lo, hi, _ = frusta_extent(train.cameras, train.bounds)
        return sfm.SfmExtent(lo, hi, "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32), num_sfm_points=7)

    monkeypatch.setattr(sfm, "sfm_extent", failed)
    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, method="reings", iterations=(2, 2, 2), device=device, with_lpips=False, eval_every=0,
              quiet=True, views=3)
    r = reings.run(**kw)
    assert r.metrics["sfm"]["method"] == "stereo" and r.metrics["sfm"]["points"] == 7
    ehps = next(s for s in r.metrics["stages"] if s["stage"] == "ehps")
    assert ehps["stereo_seeds"] > 0
    assert ehps["gaussians"] > ehps["stereo_seeds"]  # EHPS's own points stay
    r0 = reings.run(**kw, stereo_seeds=0.0)
    assert r0.metrics["sfm"]["method"] == "stereo"
    e0 = next(s for s in r0.metrics["stages"] if s["stage"] == "ehps")
    assert e0["stereo_seeds"] == 0 and e0["gaussians"] == ehps["gaussians"] - ehps["stereo_seeds"]
    rf = reings.run(**kw, extent="frusta")
    assert rf.metrics["sfm"]["method"] == "frusta"
    assert next(s for s in rf.metrics["stages"] if s["stage"] == "ehps")["stereo_seeds"] == 0


def test_stereo_seeds_auto_rule():
    from types import SimpleNamespace

    from reings.config import ReInGSConfig
    from reings.pipeline import STEREO_SEEDS_AUTO, stereo_seeds_of

    sfm, stereo = SimpleNamespace(method="sfm"), SimpleNamespace(method="stereo")
    auto = ReInGSConfig()
    assert auto.stereo_seeds is None
    assert stereo_seeds_of(auto, sfm, 3) == 0.0
    assert stereo_seeds_of(auto, sfm, 2) == STEREO_SEEDS_AUTO
    assert stereo_seeds_of(auto, stereo, 4) == STEREO_SEEDS_AUTO
    assert stereo_seeds_of(ReInGSConfig(stereo_seeds=0.0), stereo, 2) == 0.0
    assert stereo_seeds_of(ReInGSConfig(stereo_seeds=0.3), sfm, 3) == 0.3
    with pytest.raises(ValueError, match="stereo_seeds"):
        ReInGSConfig(stereo_seeds=1.5)


def test_extent_stereo_takes_the_prior_box_even_where_sfm_works(device, monkeypatch):
    import reings.data.sfm as sfm

    def must_not_run(*a, **kw):
        raise AssertionError("extent stereo must not run SfM")

    monkeypatch.setattr(sfm, "sfm_extent", must_not_run)
    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    r = reings.run(scene=scene, method="reings", iterations=(2, 2, 2), device=device, with_lpips=False,
                   eval_every=0, quiet=True, views=3, extent="stereo")
    assert r.metrics["sfm"]["method"] == "stereo"
    ehps = next(s for s in r.metrics["stages"] if s["stage"] == "ehps")
    assert ehps["stereo_seeds"] > 0  # the auto rule seeds wherever the box is the prior's
    with pytest.raises(ValueError, match="extent stereo.*depth_prior"):
        reings.run(scene=scene, method="reings", iterations=2, device=device, depth_prior="none", extent="stereo",
                   quiet=True)


def test_seeds_and_box_skip_filled_pixels_even_at_confidence_threshold_zero():
    """Confidence 0 marks a filled pixel: never a seed or a box point, even with min_conf 0
    (rng.choice would otherwise be asked for more non-zero draws than exist)."""
    from reings.reinit import stereo_box, stereo_seed_points

    scene = reings.make_procedural_scene(n_views=3, width=64, height=48, supersample=1)
    conf = np.zeros((48, 64), np.float32)
    conf[:, :20] = 0.3
    pts, _ = stereo_seed_points(scene, scene.depths, [conf] * 3, 0.9, 0.0, np.random.default_rng(0))
    assert len(pts) == 3 * 48 * 20
    box = stereo_box(scene, scene.depths, [conf] * 3, 0.0)
    assert box.n_points == 3 * 48 * 20


def test_no_pycolmap_keeps_the_frusta_and_the_stereo_box_is_recorded(device, monkeypatch):
    """A frusta box for want of pycolmap (note set) stays the frusta; a real SfM failure takes the
    stereo box, recorded in metrics.json (`sfm.stereo_points`) and in the resume settings."""
    import reings.data.sfm as sfm

    def box(note):
        def f(train, **kw):
            lo, hi, _ = frusta_extent(train.cameras, train.bounds)
            return sfm.SfmExtent(lo, hi, "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32), note=note)
        return f

    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, method="reings", iterations=(2, 2, 2), device=device, with_lpips=False, eval_every=0,
              quiet=True, views=3)
    monkeypatch.setattr(sfm, "sfm_extent", box("no pycolmap"))
    r = reings.run(**kw)
    assert r.metrics["sfm"]["method"] == "frusta" and "box" not in r.metrics["config"]
    monkeypatch.setattr(sfm, "sfm_extent", box(""))
    r = reings.run(**kw)
    assert r.metrics["sfm"]["method"] == "stereo" and r.metrics["sfm"]["stereo_points"] > 1000
    assert r.metrics["config"]["box"] == "stereo"


def test_the_fast_preset_seeds_at_every_view_count():
    from types import SimpleNamespace

    from reings.config import RUN_PRESETS, ReInGSConfig
    from reings.pipeline import stereo_seeds_of

    sfm = SimpleNamespace(method="sfm")
    fast, quick = RUN_PRESETS["fast"], RUN_PRESETS["quick"]
    assert fast.sh_degree == quick.sh_degree and fast.iterations["reings"] == (600, 600, 2400)
    assert all(fast.iterations[m] == quick.iterations[m] for m in ("3dgs", "dngaussian"))  # the baselines as quick
    assert RUN_PRESETS["quick"].stereo_seeds is None and RUN_PRESETS["paper"].stereo_seeds is None
    assert stereo_seeds_of(ReInGSConfig(), sfm, 4, fast.stereo_seeds) == 0.1
    assert stereo_seeds_of(ReInGSConfig(stereo_seeds=0.0), sfm, 4, fast.stereo_seeds) == 0.0  # the run's value wins
    assert stereo_seeds_of(ReInGSConfig(), sfm, 4, None) == 0.0


def test_a_fast_run_seeds_ehps_at_three_views(device):
    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, method="reings", iterations=(2, 2, 2), device=device, with_lpips=False, eval_every=0,
              quiet=True, views=3, extent="frusta")  # at 64x48 SfM fails, and the auto rule would seed
    fast = next(s for s in reings.run(**kw, preset="fast").metrics["stages"] if s["stage"] == "ehps")
    quick = next(s for s in reings.run(**kw, preset="quick").metrics["stages"] if s["stage"] == "ehps")
    assert fast["stereo_seed_fraction"] == 0.1 and fast["stereo_seeds"] > 0
    assert quick["stereo_seeds"] == 0 and quick["gaussians"] == fast["gaussians"] - fast["stereo_seeds"]


def test_the_fast_preset_shares_the_soft_depth_render_for_reings_only():
    """RunConfig.soft_depth_shared = none takes the preset's for the reings fits of its recipe families
    (fast and paper: both since session 18, quick: none) and leaves the baselines' recipes alone; an explicit value
    wins for every method and family."""
    from reings.config import RUN_PRESETS, RunConfig
    from reings.pipeline import run_settings, soft_depth_shared_of

    assert RUN_PRESETS["fast"].soft_depth_shared == ("llff", "dtu") and not RUN_PRESETS["quick"].soft_depth_shared
    assert RUN_PRESETS["paper"].soft_depth_shared == ("llff", "dtu")
    for fam in ("llff", "dtu"):
        assert soft_depth_shared_of(RunConfig(preset="fast"), fam)
        assert not soft_depth_shared_of(RunConfig(preset="fast", method="dngaussian"), fam)
        assert not soft_depth_shared_of(RunConfig(preset="fast", soft_depth_shared=False), fam)
        assert not soft_depth_shared_of(RunConfig(preset="quick"), fam)
        assert soft_depth_shared_of(RunConfig(preset="paper", method="dngaussian", soft_depth_shared=True), fam)
        assert not soft_depth_shared_of(RunConfig(preset="paper", method="dngaussian"), fam)
        assert not soft_depth_shared_of(RunConfig(preset="paper", soft_depth_shared=False), fam)
    assert soft_depth_shared_of(RunConfig(preset="paper"), "llff")
    assert soft_depth_shared_of(RunConfig(preset="paper"), "dtu")
    assert run_settings(RunConfig(preset="paper").resolved(), "llff")["soft_depth_shared"] is True
    assert run_settings(RunConfig(preset="paper").resolved(), "dtu")["soft_depth_shared"] is True
    assert run_settings(RunConfig(preset="fast").resolved(), "llff")["soft_depth_shared"] is True
    assert "soft_depth_shared" not in run_settings(RunConfig(preset="quick").resolved(), "llff")
