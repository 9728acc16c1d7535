"""A fit's first iterations on other views (`train.FitLead`; RunConfig.fit_scale_share: a coarse-to-fine
resolution schedule inside one fit, issue 15), and the off-frame prune (DensifyConfig.off_frame_margin).

FitLead: the fit hands its state (parameters, Adam moments, densification statistics, rng) from the lead's
trainer to a new one at iteration `until`, as a checkpoint resume does. So a lead on the fit's own views is the
same fit bit for bit (on every device: a download and an upload move bytes), a lead at 1/2 resolution renders
its iterations at 1/2 and the rest at full size, and a fit killed on either side of the switch resumes to the
uninterrupted fit's bits. The pipeline gives the fine fit of `--fit-scale 2,2,1 --fit-scale-share 1,0.5,1` a
lead of half its iterations on the views at 1/2 with the 1/2 recipe, and the rest the full-resolution recipe.

The off-frame prune: `densify.centres_in_frames` against the pinhole model's analytic cases; at a densification
step the Gaussians no training view frames go, never the whole model."""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from cases import dngaussian_fit_case, interrupt_and_resume
from reings.config import RunConfig, parse_fit_scale_share
from reings.train import FitLead, fit


@pytest.fixture(scope="module")
def case():
    return dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                               soft_depth_from=3, densify_until=25)


def _fit(case, device, lead=None, **kw):
    scene, init, cfg = case
    return fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
               log_every=5, lead=lead, **kw)


def _same(a, b):
    assert len(a) == len(b) and a.iteration == b.iteration and a.adam.step == b.adam.step
    for k in a.params:
        np.testing.assert_array_equal(a.params[k], b.params[k], err_msg=k)
        np.testing.assert_array_equal(a.adam.exp_avg[k], b.adam.exp_avg[k], err_msg=k)
        np.testing.assert_array_equal(a.adam.exp_avg_sq[k], b.adam.exp_avg_sq[k], err_msg=k)
    for k in a.stats:
        np.testing.assert_array_equal(a.stats[k], b.stats[k], err_msg=k)


def _half_lead(case, until):
    from reings.pipeline import scaled_views

    scene, _, cfg = case
    views, priors, _ = scaled_views(scene, list(scene.depths), None, 2)
    return FitLead(until, views, replace(cfg.loss, depth_patch_div=2), priors)


@pytest.mark.parametrize("engine", ["device", "host"])
def test_a_lead_on_the_fits_own_views_keeps_the_bits(device, case, engine):
    """The switch at iteration 12 (between the densifications at 10 and 20) moves the state to a new trainer:
    the same fit, bit for bit, with the same history (on the device engine a dropped download at the switch
    fails it; the host engine's trainer holds the state itself)."""
    scene, _, cfg = case
    ref = _fit(case, device, engine=engine)
    got = _fit(case, device, engine=engine, lead=FitLead(12, scene, cfg.loss, list(scene.depths)))
    _same(ref.state, got.state)
    assert got.history.densify == ref.history.densify and got.history.loss == ref.history.loss


def test_the_lead_renders_at_its_size_then_the_fit_at_its_own(device, case, monkeypatch):
    """Every forward of iterations 1-12 renders the lead's views at 1/2 (hard and soft depth passes and the
    photometric one), every forward after them the fit's views; the densification in between reads the
    statistics of the small views; the fit ends at full size with its own iteration count."""
    from reings.backends.opencl.trainer import DeviceTrainer
    from reings.train import _Iteration

    scene, _, cfg = case
    seen, now = [], [0]
    call, forward = _Iteration.__call__, DeviceTrainer.forward

    def spy_call(self, it):
        now[0] = it
        return call(self, it)

    def spy_forward(self, cam, *a, **k):
        seen.append((now[0], cam.width, cam.height))
        return forward(self, cam, *a, **k)

    monkeypatch.setattr(_Iteration, "__call__", spy_call)
    monkeypatch.setattr(DeviceTrainer, "forward", spy_forward)
    r = _fit(case, device, engine="device", lead=_half_lead(case, 12))
    assert r.state.iteration == 23 and len(r.history.densify) == 2
    w, h = scene.cameras[0].width, scene.cameras[0].height
    assert {(cw, ch) for it, cw, ch in seen if it <= 12} == {(w // 2, h // 2)}
    assert {(cw, ch) for it, cw, ch in seen if it > 12} == {(w, h)}
    assert {it for it, *_ in seen} == set(range(1, 24))


@pytest.mark.parametrize("stop_at, every", [(10, 5), (20, 5), (18, 6)])
def test_a_kill_on_either_side_of_the_switch_resumes_to_the_same_bits(device, case, tmp_path, stop_at, every):
    """Killed at the eval of iteration `stop_at` (before that iteration's checkpoint) and resumed with the same
    lead from the last checkpoint: at 5 (inside the lead, which ends at 12), at 15 (after the switch) and at 12
    (exactly at the switch: the resumed fit starts with the full views). The uninterrupted fit's state, bit for
    bit."""
    lead = _half_lead(case, 12)
    ref = _fit(case, device, engine="device", lead=lead)
    res = interrupt_and_resume(lambda **kw: _fit(case, device, engine="device", lead=lead, **kw),
                               os.path.join(tmp_path, "ck.npz"), stop_at=stop_at, every=every)
    _same(ref.state, res.state)
    np.testing.assert_array_equal(res.history.loss, ref.history.loss)


def test_the_lead_is_checked(case):
    scene, init, cfg = case
    for until in (0, 24):
        with pytest.raises(ValueError, match=r"FitLead.until must lie in \[1, 23\]"):
            fit(scene, cfg, device="reference", init=init, lead=FitLead(until, scene, cfg.loss))
    with pytest.raises(ValueError, match="FitLead holds 2 views for the fit's 3"):
        fit(scene, cfg, device="reference", init=init, lead=FitLead(5, scene.subset([0, 1]), cfg.loss))
    with pytest.raises(ValueError, match="DensifyConfig.off_frame_margin must be a finite number >= 0, got nan"):
        fit(scene, replace(cfg, densify=replace(cfg.densify, off_frame_margin=float("nan"))), device="reference",
            init=init)
    with pytest.raises(ValueError, match="LossConfig.view_warp_scale must be 1 or 2, got 3"):
        fit(scene, cfg, device="reference", init=init, lead=FitLead(5, scene, replace(cfg.loss, view_warp_scale=3)))


def test_the_share_option_parses_and_refuses():
    assert parse_fit_scale_share("1,0.5,1") == (1.0, 0.5, 1.0) and parse_fit_scale_share("0.25") == (0.25,)
    for bad, why in (("0", r"must lie in \(0, 1\], got 0"), ("1.5", "got 1.5"), ("nan", "got nan"),
                     ("1,1", "expected F or A,B,C"), ("x", "expected a number")):
        with pytest.raises(ValueError, match=why):
            parse_fit_scale_share(bad)
    with pytest.raises(ValueError, match="one share or three"):
        RunConfig(fit_scale_share=(1.0, 0.5))
    from reings.cli import build_parser, config_from_args

    args = ["run", "--fit-scale-share", "1,0.5,1", "--off-frame-margin", "0.25"]
    c = config_from_args(build_parser().parse_args(args))
    assert c.fit_scale_share == (1.0, 0.5, 1.0) and c.off_frame_margin == 0.25
    with pytest.raises(ValueError, match="must be a finite number >= 0"):
        RunConfig(off_frame_margin=-0.1)


def test_the_fine_fit_gets_a_lead_of_its_share(monkeypatch):
    """`--fit-scale 2,2,1 --fit-scale-share 1,0.5,1` on a whole run (the procedural scene, exact depths as the
    prior): the coarse fit wholly at 1/2 (no lead), the fine fit a lead of half its iterations (rounded) on the
    views and targets at 1/2 with the 1/2 recipe (patches divided by 2, the hard pass at the small views' own
    scale) and the rest on the full views with the full recipe; the final fit as before; the shares reach the
    settings and the table's tag."""
    import reings
    import reings.pipeline as P
    from reings.evaluate import _setting_tag

    got, real = [], P.fit

    def size(views):
        ims = views.images if hasattr(views, "images") else [v[0] for v in views]
        return ims[0].shape[:2]

    def spy_fit(views, recipe, lead=None, **k):
        got.append((k.get("desc"), size(views), recipe.loss.depth_patch_div, recipe.loss.hard_depth_scale,
                    None if lead is None else (lead.until, size(lead.views), lead.loss.depth_patch_div,
                                               lead.loss.hard_depth_scale, lead.depth_targets[0].shape,
                                               (lead.densify.max_screen_size, recipe.densify.max_screen_size))))
        return real(views, recipe, lead=lead, **k)

    monkeypatch.setattr("reings.pipeline.fit", spy_fit)
    r = reings.run(method="reings", iterations=5, quiet=True, with_lpips=False, eval_every=0, fit_scale=(2, 2, 1),
                   fit_scale_share=(1.0, 0.5, 1.0), max_screen_fraction=1.0)
    (c, cs, cd, ch, cl), (f, fs, fd, fh, fl), (z, zs, zd, zh, zl) = got
    assert (c, f, z) == ("coarse", "fine", "final")
    h, w = fs
    assert cs == (h // 2, w // 2) and (cd, ch, cl) == (2, 1, None)
    side = max(h, w)  # the screen prune's bound in each part's own pixels
    assert (fd, fh) == (1, 2) and fl == (2, (h // 2, w // 2), 2, 1, (h // 2, w // 2), (side / 2, side))  # round(2.5)
    assert zs == (h, w) and (zd, zh, zl) == (1, 2, None)
    cfg = r.metrics["config"]
    assert cfg["fit_scale"] == [2, 2, 1] and cfg["fit_scale_share"] == [1.0, 0.5, 1.0]
    lead = {st["stage"]: st.get("lead") for st in r.metrics["stages"] if "iterations" in st}
    assert lead["coarse"] is None and lead["final"] is None and lead["fine"]["until"] == 2
    assert lead["fine"]["config"]["loss"]["depth_patch_div"] == 2 and lead["fine"]["fit_scale"] == 2
    assert "scale 2/2/1 share 1/0.5/1" in _setting_tag({"method": "reings", "preset": "paper", "config": cfg})


def test_the_share_is_recorded_and_noted_only_where_it_acts():
    from reings.pipeline import option_notes, run_settings

    def notes(**kw):
        return [n for n in option_notes(RunConfig(**kw).resolved(), "llff", 3) if "fit_scale_share" in n]

    assert notes(fit_scale=(1,), fit_scale_share=(0.5,)) and notes(fit_scale_share=(1, 0.5, 1))  # 2,1,1: coarse 1
    assert not notes(fit_scale_share=(0.5,)) and not notes(fit_scale=(1,), fit_scale_share=(1,))
    s = run_settings(RunConfig(fit_scale_share=(0.5, 0.5, 0.5)).resolved(), "llff")
    assert s["fit_scale_share"] == [0.5, 1.0, 1.0]  # the default 2,1,1: only the coarse fit is at a scale
    assert "fit_scale_share" not in run_settings(RunConfig(fit_scale_share=(1,)).resolved(), "llff")
    assert "fit_scale_share" not in run_settings(RunConfig(fit_scale=(1,), fit_scale_share=(0.5,)).resolved(), "llff")


def _camera(w=100, h=80, f=100.0):
    from reings.types import Camera

    return Camera(np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]), np.eye(4), w, h)


def test_centres_in_frames_analytic():
    """A camera at the origin looking down +z (100 x 80, f 100, centre (50, 40)): u = 50 + 100 x / z."""
    from reings.densify import centres_in_frames

    cam = _camera()
    pts = np.array([[0, 0, 1],          # the image's centre
                     [0.5, 0, 1],       # u = 100: on the right edge
                     [0.51, 0, 1],      # u = 101: just outside
                     [1.0, 0, 1],       # u = 150: a margin of 0.5 (50 px) reaches it
                     [0, -0.4, 1],      # v = 0: the top edge
                     [0, 0, -1],        # behind the camera
                     [0, 0, 0.005]])    # in front of the near plane 0.01
    np.testing.assert_array_equal(centres_in_frames(pts, [cam], 0.0), [1, 1, 0, 0, 1, 0, 0])
    np.testing.assert_array_equal(centres_in_frames(pts, [cam], 0.5), [1, 1, 1, 1, 1, 0, 0])
    np.testing.assert_array_equal(centres_in_frames(pts, [cam], 0.49), [1, 1, 1, 0, 1, 0, 0])
    # a second camera turned round (looking down -z) frames the point behind the first
    turned = replace(cam, viewmat=np.diag([-1.0, 1.0, -1.0, 1.0]))
    np.testing.assert_array_equal(centres_in_frames(pts, [cam, turned], 0.0), [1, 1, 0, 0, 1, 1, 0])
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="off_frame_margin must be a finite number >= 0"):
            centres_in_frames(pts, [cam], bad)


def test_the_off_frame_prune_at_a_densification_step():
    """densify_rows with off_frame_margin: the Gaussians no training view frames go at a densification step
    (counted), the others keep their rows; none at a step that does not densify; never the whole model."""
    from cases import densify_state as state

    from reings.backends.reference_state import HeldRows
    from reings.config import DensifyConfig
    from reings.densify import densify_rows

    cfg = DensifyConfig(densify_from=0, densify_until=100, densify_interval=10, prune_opacity=0.0,
                        off_frame_margin=0.0)
    rng = np.random.default_rng(0)
    st = state([[0, 0, 2], [3, 0, 2], [0, 0, 3], [0, 0, -2]])
    out = densify_rows(HeldRows(st), cfg, 10, 1.0, rng, cameras=[_camera()])
    assert out["off_frame"] == 2 and out["n"] == 2
    np.testing.assert_array_equal(st.params["means"], [[0, 0, 2], [0, 0, 3]])
    st = state([[3, 0, 2], [0, 0, 3]])
    assert densify_rows(HeldRows(st), cfg, 15, 1.0, rng, cameras=[_camera()]) is None  # not a step
    assert len(st) == 2
    st = state([[3, 0, 2], [0, 0, -2]])
    out = densify_rows(HeldRows(st), cfg, 10, 1.0, rng, cameras=[_camera()])
    assert out["off_frame"] == 0 and len(st) == 2  # every one off frame: the model is kept
    out = densify_rows(HeldRows(st), replace(cfg, off_frame_margin=None), 10, 1.0, rng, cameras=[_camera()])
    assert "off_frame" not in (out or {})


def test_the_margin_reaches_the_reings_recipes_only():
    from test_recipe_family import _ctx

    from reings.pipeline import run_settings, soft_depth_recipe

    ctx, _ = _ctx("llff", off_frame_margin=0.25)
    assert {ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), st).densify.off_frame_margin
            for st in ("coarse", "fine", "final")} == {0.25}
    assert run_settings(ctx.cfg, "llff")["off_frame_margin"] == 0.25
    ctx, _ = _ctx("llff")
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), "final").densify.off_frame_margin is None
    assert "off_frame_margin" not in run_settings(ctx.cfg, "llff")
    ctx, _ = _ctx("llff", method="dngaussian", off_frame_margin=0.25)
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff")).densify.off_frame_margin is None


def test_the_off_frame_prune_in_a_fit_on_both_engines(device, case):
    """A fit with off_frame_margin 0: the Gaussians the training views do not frame go at its densifications (the
    case's random points fill a box larger than the views' frusta), the same rows on both engines; the returned
    model's centres all lie in some training view's frame."""
    from cases import prune_on_both_engines

    from reings.densify import centres_in_frames

    scene, init, cfg = case
    cfg = replace(cfg, densify=replace(cfg.densify, off_frame_margin=0.0))
    run = prune_on_both_engines(scene, init, cfg, device, "off_frame")
    # the last densification (20) judged the centres as they were then; 3 iterations moved them a little since
    assert centres_in_frames(run.gaussians.means, scene.cameras, 0.05).all()


def test_the_screen_prune_is_in_each_parts_own_pixels():
    """--max-screen-fraction F: the size prune from the densification's start at F times the largest image side
    in the fit's own pixels: the coarse fit at 1/2 half of it, and with a lead its 1/2 part half, its full part
    whole; the world-size prune stays off. Recorded in the settings and noted for the baselines."""
    from test_recipe_family import _ctx

    from reings.pipeline import option_notes, run_settings, soft_depth_recipe

    ctx, cam = _ctx("llff", max_screen_fraction=1.0)
    side = max(cam.width, cam.height)
    r = {st: ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), st).densify for st in ("coarse", "fine")}
    assert r["coarse"].max_screen_size == side / 2 and r["fine"].max_screen_size == side
    assert r["fine"].size_prune_from == r["fine"].densify_from and r["fine"].max_world_size is None
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), "coarse", fit_scale=1).densify.max_screen_size == side
    assert run_settings(ctx.cfg, "llff")["max_screen_fraction"] == 1.0
    base = RunConfig(method="dngaussian", max_screen_fraction=1.0, off_frame_margin=0.1).resolved()
    assert {n.split()[0] for n in option_notes(base, "llff", 3)} >= {"max_screen_fraction", "off_frame_margin"}
