"""LossConfig.hard_depth_scale: the hard depth pass at 1/scale of the training resolution (issue 15).

The pass's camera (`depth_pass_camera`) against the pinhole model in float64: a point the full camera
puts at pixel coordinate u lands at u / scale, so pixel (i, j) of the small image covers the full
image's scale x scale block; the prior's block mean (`block_mean`) against a loop in float64. Then the
fit: the hard pass renders at the small size against the block-mean target (its depth loss called
with that frame and the view's index among the small targets), the two engines agree (bit for bit on
PoCL), and the fit differs from the full-resolution one (the switch does something)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import assert_engines_agree, dngaussian_fit_case
from reings.config import RunConfig
from reings.train import block_mean, depth_pass_camera, fit
from reings.types import Camera


def _camera(w=67, h=45, seed=0):
    rng = np.random.default_rng(seed)
    K = np.array([[60.0 + rng.random(), 0, w / 2 + rng.random()], [0, 58.0 + rng.random(), h / 2 - rng.random()],
                  [0, 0, 1]])
    V = np.eye(4)
    V[:3, 3] = rng.normal(size=3) * 0.1
    return Camera(K, V, w, h)


def _pixel(cam, X):
    """float64 pinhole projection of world points X [n, 3]: continuous pixel coordinates (u, v)."""
    x = X @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    return cam.K[0, 0] * x[:, 0] / x[:, 2] + cam.K[0, 2], cam.K[1, 1] * x[:, 1] / x[:, 2] + cam.K[1, 2]


@pytest.mark.parametrize("scale", [2, 4])
def test_the_pass_camera_maps_each_block_to_one_pixel(scale):
    cam = _camera()
    small = depth_pass_camera(cam, scale)
    assert (small.width, small.height) == (67 // scale, 45 // scale)  # the partial blocks dropped
    X = np.random.default_rng(1).normal(size=(200, 3)) + [0, 0, 6]
    u, v = _pixel(cam, X)
    us, vs = _pixel(small, X)
    np.testing.assert_allclose(us, u / scale, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vs, v / scale, rtol=0, atol=1e-12)
    # so the pixel containing u / scale is the block containing u
    inside = (u >= 0) & (v >= 0) & (u < small.width * scale) & (v < small.height * scale)
    assert inside.sum() > 50
    np.testing.assert_array_equal(np.floor(us[inside]), np.floor(u[inside]) // scale)
    assert depth_pass_camera(cam, 1) is cam


def test_block_mean_against_a_loop():
    a = np.random.default_rng(2).random((13, 10)).astype(np.float32) * 7
    for s in (2, 4):
        ref = np.array([[np.mean(a[i * s:i * s + s, j * s:j * s + s].astype(np.float64)) for j in range(10 // s)]
                        for i in range(13 // s)])
        got = block_mean(a, s)
        assert got.dtype == np.float32 and got.shape == ref.shape
        np.testing.assert_array_equal(got, ref.astype(np.float32))


def test_refusals(case):
    scene, init, cfg = case
    for bad in (3, 0):
        with pytest.raises(ValueError, match="hard_depth_scale must be 1, 2 or 4"):
            fit(scene, replace(cfg, loss=replace(cfg.loss, hard_depth_scale=bad)), device="reference", init=init,
                depth_targets=list(scene.depths))
    with pytest.raises(ValueError, match="hard_depth_scale must be 1, 2 or 4, got 3"):
        RunConfig(hard_depth_scale=3)
    with pytest.raises(ValueError, match="no 4x4 block"):
        depth_pass_camera(_camera(w=3, h=9), 4)


@pytest.fixture(scope="module")
def case():
    return dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=12,
                               soft_depth_from=3, densify_until=25)


def _fit(case, device, scale, engine, **kw):
    scene, init, cfg = case
    cfg = replace(cfg, loss=replace(cfg.loss, hard_depth_scale=scale))
    return fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
               engine=engine, **kw)


def test_the_hard_pass_renders_small_against_the_block_means(device, case, monkeypatch):
    from reings.backends.opencl.trainer import DeviceTrainer

    seen, uploaded = [], {}
    depth_loss, upload = DeviceTrainer.depth_loss, DeviceTrainer.upload_depth_targets

    def spy_loss(self, fr, view, *a, **k):
        seen.append((view, fr.width, fr.height))
        return depth_loss(self, fr, view, *a, **k)

    def spy_upload(self, targets, shapes, *a, **k):
        uploaded["targets"], uploaded["shapes"] = targets, shapes
        return upload(self, targets, shapes, *a, **k)

    monkeypatch.setattr(DeviceTrainer, "depth_loss", spy_loss)
    monkeypatch.setattr(DeviceTrainer, "upload_depth_targets", spy_upload)
    scene = case[0]
    _fit(case, device, 2, "device")
    assert uploaded["shapes"] == [(48, 64)] * 3 + [(24, 32)] * 3
    for i in range(3):
        np.testing.assert_array_equal(uploaded["targets"][3 + i], block_mean(scene.depths[i], 2))
    hard = [s for s in seen if s[1] == 32]
    soft = [s for s in seen if s[1] == 64]
    assert len(hard) == 12 and all(v >= 3 and h == 24 for v, _, h in hard)  # one hard pass per iteration
    assert len(soft) == 12 - 3 + 1 and all(v < 3 for v, _, _ in soft)  # the soft term: full size, own targets


@pytest.mark.parametrize("patches, lo_hi", [("pixels", (5, 17)), ("area", (5, 17)), ("area", (1, 60))])
def test_the_patch_sizes_of_the_hard_pass(device, case, monkeypatch, patches, lo_hi):
    """LossConfig.hard_depth_patches: each depth loss call gets the sizes its draw made ('pixels', and
    the soft term always), or for the hard pass at scale 2 with 'area' each drawn size (capped at the full
    frame's 48 rows) halved, rounded up, within [2, the small frame's 24 rows]."""
    from reings import losses
    from reings.backends.opencl.trainer import DeviceTrainer

    drawn, got = [], []
    draw, depth_loss = losses.draw_depth_patches, DeviceTrainer.depth_loss

    def spy_draw(*a, **k):
        drawn.append(draw(*a, **k))
        return drawn[-1]

    def spy_loss(self, fr, view, pl, pg, *a, **k):
        got.append((fr.width, pl, pg))
        return depth_loss(self, fr, view, pl, pg, *a, **k)

    monkeypatch.setattr(losses, "draw_depth_patches", spy_draw)
    monkeypatch.setattr(DeviceTrainer, "depth_loss", spy_loss)
    scene, init, cfg = case
    cfg = replace(cfg, loss=replace(cfg.loss, hard_depth_scale=2, hard_depth_patches=patches,
                                    depth_patch_range=lo_hi))
    fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False, engine="device")
    assert len(drawn) == len(got) == 12 + 10  # one draw per depth loss call: 12 hard, 10 soft
    odd = 0
    for (pl, pg), (w, ql, qg) in zip(drawn, got):
        assert max(pl, pg) <= 48
        if patches == "area" and w == 32:
            assert (ql, qg) == tuple(min(max(2, -(-p // 2)), 24) for p in (pl, pg))
            odd += bool(pl % 2 or pg % 2) and min(pl, pg) > 3
        else:
            assert (ql, qg) == (pl, pg)
    assert patches == "pixels" or odd  # an odd size was drawn: rounding up, not down, is checked
    if lo_hi == (1, 60):  # the floor and the cap were both met
        hard = [q for (w, *qs) in got if w == 32 for q in qs]
        assert min(hard) == 2 and max(hard) == 24


def test_engines_agree_and_the_scale_changes_the_fit(device, case):
    host = _fit(case, device, 2, "host")
    dev = _fit(case, device, 2, "device")
    assert host.history.n_gaussians == dev.history.n_gaussians
    assert_engines_agree(device, host.state, dev.state, "hard_depth_scale 2")
    full = _fit(case, device, 1, "device")
    assert not np.array_equal(full.state.params["means"][:50], dev.state.params["means"][:50])


def test_weights_and_the_metric_term_at_scale_2(device, case, monkeypatch):
    """With the prior's confidence weighting the depth loss and the metric depth term on: the host
    engine's uploads hold the block means of the targets and of the weights at n + i (the metric
    term's own n weights padded), and the engines agree."""
    from reings.backends.host_trainer import HostTrainer
    from reings.backends.reference_loss import depth_confidence_weights

    scene, init, cfg = case
    rng = np.random.default_rng(3)
    conf = [rng.random(d.shape).astype(np.float32) for d in scene.depths]
    cfg = replace(cfg, loss=replace(cfg.loss, hard_depth_scale=2, depth_confidence=0.5, depth_metric=0.1))
    seen = {}
    upload, metric = HostTrainer.upload_depth_targets, HostTrainer.upload_depth_metric

    def spy(self, targets, shapes, *a, **k):
        out = upload(self, targets, shapes, *a, **k)
        seen["targets"], seen["weights"] = list(self.targets), list(self.dweights)
        return out

    def spy_metric(self, weights):
        seen["metric"] = list(weights)
        return metric(self, weights)

    monkeypatch.setattr(HostTrainer, "upload_depth_targets", spy)
    monkeypatch.setattr(HostTrainer, "upload_depth_metric", spy_metric)
    runs = {e: fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), depth_confidence=conf,
                   progress=False, engine=e) for e in ("host", "device")}
    for i in range(3):
        np.testing.assert_array_equal(seen["targets"][3 + i], block_mean(scene.depths[i], 2))
        np.testing.assert_array_equal(seen["weights"][3 + i], block_mean(depth_confidence_weights(conf[i], 0.5), 2))
        np.testing.assert_array_equal(seen["weights"][i], depth_confidence_weights(conf[i], 0.5))
    assert len(seen["metric"]) == 6 and all(w is None for w in seen["metric"][3:])
    assert_engines_agree(device, runs["host"].state, runs["device"].state, "hard_depth_scale 2, weighted, metric")


@pytest.mark.parametrize("method, family, kw, want", [
    ("reings", "llff", {}, 2), ("reings", "dtu", {}, 1),  # the family defaults (reings only)
    ("dngaussian", "llff", {}, 1), ("dngaussian", "dtu", {}, 1),
    ("reings", "llff", {"hard_depth_scale": 1}, 1), ("reings", "dtu", {"hard_depth_scale": 2}, 2),
    ("dngaussian", "llff", {"hard_depth_scale": 4}, 4), ("reings", "llff", {"depth_prior": "none"}, 1),
    ("reings", "llff", {"depth_prior": "none", "hard_depth_scale": 2}, 2)])
def test_the_scale_reaches_the_fits(method, family, kw, want):
    """RunConfig.hard_depth_scale = none: the recipe family's for the reings fits (2 for 'llff', 1 for 'dtu'; 1
    without a depth prior, where no hard pass runs), 1 for the baselines; a value wins everywhere. The fits' recipes carry it with the patch rule; run_settings records it
    (absent at 1, so older run folders resume) with 'area' (absent at 'pixels')."""
    from test_recipe_family import _ctx

    from reings.pipeline import HARD_DEPTH_SCALE_BY_FAMILY, baseline_recipe, hard_depth_scale_of, run_settings

    assert HARD_DEPTH_SCALE_BY_FAMILY == {"llff": 2, "dtu": 1}
    ctx, _ = _ctx(family, method=method, **kw)
    r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family))
    assert r.loss.hard_depth_scale == want == hard_depth_scale_of(ctx.cfg, family)
    assert r.loss.hard_depth_patches == ("area" if want > 1 else "pixels")
    s = run_settings(ctx.cfg, "dtu" if family == "dtu" else "llff")
    assert s.get("hard_depth_scale") == (want if want > 1 else None)
    assert s.get("hard_depth_patches") == ("area" if want > 1 else None)
    ctx, _ = _ctx(family, method=method, hard_depth_patches="pixels", **kw)
    assert ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family)).loss.hard_depth_patches == "pixels"
    assert "hard_depth_patches" not in run_settings(ctx.cfg, "dtu" if family == "dtu" else "llff")


def test_eval_counts_runs_of_another_hard_pass_as_not_done(tmp_path):
    """`reings eval`'s reuse check: a finished LLFF reings run from before the default (no hard_depth_scale in its
    settings: the full pass) and one of the old option (scale 2 without hard_depth_patches: 'pixels') differ from
    what the defaults ask now; a run of the default does not."""
    import json

    from reings.config import RunConfig
    from reings.evaluate import _settings_differ
    from reings.pipeline import run_settings

    cfg = RunConfig()
    now = json.loads(json.dumps(run_settings(cfg.resolved(), "llff")))
    assert now["hard_depth_scale"] == 2 and now["hard_depth_patches"] == "area"
    runs = {"now": now, "full": {k: v for k, v in now.items() if not k.startswith("hard_depth")},
            "pixels": {k: v for k, v in now.items() if k != "hard_depth_patches"}}
    for name, config in runs.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(json.dumps({"config": config}))
    assert _settings_differ(str(tmp_path / "now" / "metrics.json"), cfg, "llff") == ""
    assert "hard_depth_scale" in _settings_differ(str(tmp_path / "full" / "metrics.json"), cfg, "llff")
    assert "hard_depth_patches" in _settings_differ(str(tmp_path / "pixels" / "metrics.json"), cfg, "llff")
