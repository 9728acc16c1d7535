"""The near prune (RunConfig.near_prune -> DensifyConfig.near_prune_radius): at each densification step of a
reings fit the Gaussians whose centre lies within F times the scene's near depth of a training camera's centre
go (DNGaussian's LLFF near pruning, on the training cameras only: docs/method.md §14).

Checked against analytic cases: `densify.away_from_cameras` (distances to camera centres), `pipeline.near_depth`
(the smallest per-view percentile of the SfM points' depths), `densify_rows` with both geometric rules (one
surgery, each rule's own count, never the whole model), and the option's path into the reings recipes, the
settings and the notes."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reings.config import RunConfig
from reings.types import Camera


def _camera(centre=(0.0, 0.0, 0.0)):
    """A camera looking down +z from `centre` (100 x 80, f 100)."""
    vm = np.eye(4)
    vm[:3, 3] = -np.asarray(centre, np.float64)  # R = I: t = -R c
    return Camera(np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]]), vm, 100, 80)


def test_away_from_cameras_analytic():
    from reings.densify import away_from_cameras

    cams = [_camera(), _camera((10.0, 0.0, 0.0))]
    pts = np.array([[0, 0, 1.0],      # 1 from camera 0
                    [0, 0, -2.0],     # 2 behind camera 0: distance, not depth
                    [10, 2, 0.0],     # 2 from camera 1
                    [5, 0, 0.0],      # 5 from both
                    [3, 4, 0.0]])     # exactly 5 from camera 0: kept at radius 5
    np.testing.assert_array_equal(away_from_cameras(pts, cams, 0.0), [1, 1, 1, 1, 1])
    np.testing.assert_array_equal(away_from_cameras(pts, cams, 1.5), [0, 1, 1, 1, 1])
    np.testing.assert_array_equal(away_from_cameras(pts, cams, 2.5), [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(away_from_cameras(pts, cams, 5.0), [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(away_from_cameras(pts, cams, 5.01), [0, 0, 0, 0, 0])
    np.testing.assert_array_equal(away_from_cameras(pts, cams[1:], 2.5), [1, 1, 0, 1, 1])
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="near_prune_radius must be a finite number >= 0"):
            away_from_cameras(pts, cams, bad)


def test_near_depth_is_the_smallest_percentile_over_the_views():
    from test_recipe_family import _ctx

    from reings.data.sfm import SfmExtent
    from reings.pipeline import near_depth

    ctx, cam = _ctx("llff", near_prune=0.25)  # SfM points straight ahead of camera 0 at depths 2, 4, 6
    assert ctx.near_depth == pytest.approx(2.04, abs=1e-9)  # numpy's linear percentile: 2 + 0.01 * 2 * (4 - 2)
    assert _ctx("llff")[0].near_depth is None  # not computed when the option is off
    assert near_depth([cam], ctx.box, 50.0) == pytest.approx(4.0, abs=1e-9)
    # a second camera 1 unit further back sees them at 3, 5, 7; the first's nearer percentile wins
    back = replace(cam, viewmat=cam.viewmat.copy())
    back.viewmat[2, 3] += 1.0
    assert near_depth([back, cam], ctx.box) == pytest.approx(2.04, abs=1e-9)
    assert near_depth([back], ctx.box) == pytest.approx(3.04, abs=1e-9)
    empty = SfmExtent(np.zeros(3), np.ones(3), "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32))
    assert near_depth([cam], empty) is None


def test_the_near_prune_at_a_densification_step():
    """densify_rows with near_prune_radius: the Gaussians near a training camera go at a densification step,
    counted; with the off-frame prune too, one surgery and each rule counting the ones it adds; never the whole
    model; nothing at a step that does not densify."""
    from cases import densify_state as _state

    from reings.backends.reference_state import HeldRows
    from reings.config import DensifyConfig
    from reings.densify import densify_rows

    cfg = DensifyConfig(densify_from=0, densify_until=100, densify_interval=10, prune_opacity=0.0,
                        near_prune_radius=1.5)
    rng = np.random.default_rng(0)
    cams = [_camera()]
    st = _state([[0, 0, 1], [0, 0, 2], [3, 0, 2], [0, 0, -1]])
    out = densify_rows(HeldRows(st), cfg, 10, 1.0, rng, cameras=cams)
    assert out["near"] == 2 and out["n"] == 2 and "off_frame" not in out
    np.testing.assert_array_equal(st.params["means"], [[0, 0, 2], [3, 0, 2]])
    # both rules: [3, 0, 2] is off frame (u = 200), [0, 0, 1] near, [0, 0, -1] both (counted once, by the first)
    st = _state([[0, 0, 1], [0, 0, 2], [3, 0, 2], [0, 0, -1]])
    out = densify_rows(HeldRows(st), replace(cfg, off_frame_margin=0.0), 10, 1.0, rng, cameras=cams)
    assert (out["off_frame"], out["near"], out["n"]) == (2, 1, 1)
    np.testing.assert_array_equal(st.params["means"], [[0, 0, 2]])
    st = _state([[0, 0, 1], [0, 0, 0.5]])
    assert densify_rows(HeldRows(st), cfg, 15, 1.0, rng, cameras=cams) is None  # not a step
    out = densify_rows(HeldRows(st), cfg, 10, 1.0, rng, cameras=cams)
    assert out["near"] == 0 and len(st) == 2  # every one near: the model is kept
    out = densify_rows(HeldRows(st), cfg, 10, 1.0, rng)  # no cameras (maybe_densify): no rule
    assert "near" not in (out or {})


def test_the_radius_reaches_the_reings_recipes_only():
    from test_recipe_family import _ctx

    from reings.evaluate import _ABSENT_WHEN_OFF
    from reings.pipeline import option_notes, run_settings, soft_depth_recipe

    ctx, _ = _ctx("llff", near_prune=0.25)
    assert [ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), st).densify.near_prune_radius
            for st in ("coarse", "fine", "final")] == pytest.approx([0.25 * 2.04] * 3)
    assert run_settings(ctx.cfg, "llff")["near_prune"] == 0.25 and "near_prune" in _ABSENT_WHEN_OFF
    ctx, _ = _ctx("llff")
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), "final").densify.near_prune_radius is None
    assert "near_prune" not in run_settings(ctx.cfg, "llff")
    ctx, _ = _ctx("llff", method="dngaussian", near_prune=0.25)
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff")).densify.near_prune_radius is None
    assert any(n.startswith("near_prune applies to the reings fits only") for n in option_notes(ctx.cfg, "llff", 3))
    ctx, _ = _ctx("llff", near_prune=0.25)
    ctx.near_depth = None  # no points in the box: no scale
    assert ctx.run_recipe(soft_depth_recipe(600, 0, "llff"), "final").densify.near_prune_radius is None


def test_a_box_without_points_gets_a_note(capsys):
    import reings
    from reings.data.sfm import SfmExtent
    from reings.pipeline import RunContext

    scene = reings.make_procedural_scene(n_views=3, width=32, height=24, supersample=1)
    box = SfmExtent(np.zeros(3), np.ones(3), "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32))
    ctx = RunContext(RunConfig(near_prune=0.25).resolved(), None, scene.subset([0]), scene.subset([1]), None, box,
                     print, False)
    assert ctx.near_depth is None
    assert "--near-prune needs the scene box's points" in capsys.readouterr().out


def test_the_option_parses_and_refuses():
    from reings.cli import build_parser, config_from_args

    assert config_from_args(build_parser().parse_args(["run", "--near-prune", "0.25"])).near_prune == 0.25
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="near_prune must be a finite number >= 0"):
            RunConfig(near_prune=bad)


def test_the_radius_is_checked_by_fit():
    from cases import dngaussian_fit_case

    from reings.train import fit

    scene, init, cfg = dngaussian_fit_case(n_views=2, width=32, height=24, n_points=50, sh_degree=0, iterations=3,
                                           soft_depth_from=2, densify_until=3)
    with pytest.raises(ValueError, match="DensifyConfig.near_prune_radius must be a finite number >= 0, got -1"):
        fit(scene, replace(cfg, densify=replace(cfg.densify, near_prune_radius=-1.0)), device="reference",
            init=init, progress=False)


def test_the_near_prune_in_a_fit_on_both_engines(device):
    """A fit whose radius takes the nearest tenth of its initial points: the same rows go on both engines at its
    densifications, and the returned model keeps its distance from the training cameras."""
    from cases import dngaussian_fit_case, prune_on_both_engines

    from reings.densify import away_from_cameras

    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    means = np.asarray(init.means, np.float64)
    dist = np.min([np.linalg.norm(means - c.center, axis=1) for c in scene.cameras], axis=0)
    radius = float(np.percentile(dist, 10))
    cfg = replace(cfg, densify=replace(cfg.densify, near_prune_radius=radius))
    run = prune_on_both_engines(scene, init, cfg, device, "near")
    # the last densification (20) judged the centres as they were then; 3 iterations moved them a little since
    assert away_from_cameras(run.gaussians.means, scene.cameras, 0.9 * radius).all()
