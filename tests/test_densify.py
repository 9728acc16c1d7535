"""Densification on small synthetic states: statistics in NDC units, clone / split / prune as
3DGS with DNGaussian thresholds, cap, opacity reset, clean_views, schedule; moments aligned."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reings import densify as D
from reings.config import DensifyConfig, preset
from reings.state import TrainState
from reings.types import Gaussians


def _logit(p):
    return np.log(p / (1 - p))


def _state(n=6, opacity=0.5, log_scale=-5.0, rng=None):
    rng = rng or np.random.default_rng(0)
    g = Gaussians(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), np.full((n, 3), log_scale),
                  np.full(n, _logit(opacity)), rng.normal(size=(n, 4, 3)))
    st = TrainState.from_gaussians(g)
    for k in st.params:  # non-zero moments, to see who keeps them
        st.adam.exp_avg[k][...] = 1.0
        st.adam.exp_avg_sq[k][...] = 2.0
    D.init_stats(st)
    return st


CFG = DensifyConfig(grad_threshold=0.001, percent_dense=0.01, split_opacity_thresh=None, prune_opacity=0.005)


def test_ndc_grad_norm_units():
    v = np.array([[1e-6, 0.0], [0.0, 2e-6], [3e-6, 4e-6]])
    g = D.ndc_grad_norm(v, width=504, height=378)
    np.testing.assert_allclose(g, [1e-6 * 252, 2e-6 * 189, np.hypot(3e-6 * 252, 4e-6 * 189)], rtol=1e-6)


def test_accumulate_mean_over_visible_views():
    st = _state(3)
    D.accumulate(st, np.array([1.0, 2.0, 3.0]), np.array([True, False, True]), radii=np.array([4, 9, 2]))
    D.accumulate(st, np.array([3.0, 5.0, 0.0]), np.array([True, False, False]), radii=np.array([3, 9, 7]))
    np.testing.assert_allclose(D.mean_grads(st), [2.0, 0.0, 3.0])
    np.testing.assert_array_equal(st.stats[D.COUNT], [2, 0, 1])
    np.testing.assert_array_equal(st.stats[D.RADII], [4, 0, 2])  # invisible views don't count
    with pytest.raises(ValueError):
        D.accumulate(st, np.zeros(2), np.ones(2, bool))


def test_clone_split_prune():
    rng = np.random.default_rng(1)
    st = _state(6, rng=rng)
    extent = 1.0
    st.params["log_scales"][3:] = np.log(0.05)  # big -> split (0.05 > 0.01 * extent)
    st.params["opacity_logits"][5] = _logit(0.001)  # prunable
    st.params["quats"][4] = [np.cos(0.3), 0, 0, np.sin(0.3)]
    hot = np.array([True, True, False, True, True, False])  # rows 0,1 clone; 3,4 split
    D.accumulate(st, np.where(hot, 0.01, 0.0001).astype(np.float32), np.ones(6, bool))
    means0 = st.params["means"].copy()
    out = D.densify_and_prune(st, CFG, extent, rng)
    assert out == {"cloned": 2, "split": 2, "pruned": 1, "n": 6 + 2 + 2 - 1}
    # rows: kept [0,1,2,5] -> 5 pruned -> [0,1,2], clones [0,1], children of 3,4 tiled [3,4,3,4]
    p = st.params
    np.testing.assert_array_equal(p["means"][:3], means0[:3])
    np.testing.assert_array_equal(p["means"][3:5], means0[:2])
    np.testing.assert_allclose(p["log_scales"][5:], np.log(0.05 / 1.6), rtol=1e-6)
    np.testing.assert_array_equal(p["sh_rest"][5:], np.concatenate([st.params["sh_rest"][5:7]] * 2))
    # children within a few sigma of their parent
    d = np.linalg.norm(p["means"][5:] - np.concatenate([means0[3:5]] * 2), axis=1)
    assert np.all(d < 5 * 0.05 * np.sqrt(3)) and np.all(d > 0)
    # kept rows keep their moments, new rows have zero moments, all arrays aligned
    for k in p:
        assert st.adam.exp_avg[k].shape == p[k].shape
        assert np.all(st.adam.exp_avg[k][:3] == 1.0) and np.all(st.adam.exp_avg[k][3:] == 0.0)
    # statistics reset
    assert np.all(st.stats[D.ACCUM] == 0) and st.stats[D.COUNT].shape == (9,)


def test_split_samples_follow_rotation_and_scale():
    """Many children of one anisotropic rotated Gaussian: empirical covariance = R S^2 R^T."""
    rng = np.random.default_rng(2)
    st = _state(1, rng=rng)
    st.params["log_scales"][0] = np.log([0.5, 0.1, 0.02])
    q = np.array([0.9, 0.2, -0.3, 0.1])
    st.params["quats"][0] = q
    st.params["means"][0] = [1, 2, 3]
    D.accumulate(st, np.array([1.0], np.float32), np.ones(1, bool))
    cfg = replace(CFG, split_n=20000)
    D.densify_and_prune(st, cfg, 1.0, rng)
    x = st.params["means"].astype(np.float64)
    R = D.quat_to_rotmat(q[None])[0]
    cov = R @ np.diag([0.5, 0.1, 0.02]) ** 2 @ R.T
    np.testing.assert_allclose(np.cov(x.T), cov, atol=0.01 * 0.25)
    np.testing.assert_allclose(x.mean(0), [1, 2, 3], atol=0.02)


def test_dngaussian_opacity_gate_and_size_prune():
    rng = np.random.default_rng(3)
    st = _state(4, opacity=0.05, rng=rng)  # all below split_opacity_thresh 0.1
    D.accumulate(st, np.full(4, 1.0, np.float32), np.ones(4, bool), radii=np.array([1, 30, 1, 1]))
    cfg = replace(preset("dngaussian").densify, max_screen_size=20.0)
    out = D.densify_and_prune(st, cfg, 1.0, rng)
    assert out["cloned"] == 0 and out["split"] == 0 and out["pruned"] == 0  # size prune off
    D.accumulate(st, np.zeros(4, np.float32), np.ones(4, bool), radii=np.array([1, 30, 1, 1]))
    out = D.densify_and_prune(st, cfg, 1.0, rng, size_prune=True)
    assert out["pruned"] == 1 and len(st) == 3


def test_cap_keeps_highest_gradients():
    rng = np.random.default_rng(4)
    st = _state(6, rng=rng)
    g = np.array([0.01, 0.05, 0.02, 0.04, 0.03, 0.0], np.float32)
    st.params["means"][:, 0] = np.arange(6)
    D.accumulate(st, g, np.ones(6, bool))
    out = D.densify_and_prune(st, replace(CFG, max_gaussians=8), 1.0, rng)
    assert out["cloned"] == 2 and len(st) == 8
    np.testing.assert_array_equal(st.params["means"][6:, 0], [1, 3])  # the two hottest


def test_reset_opacity_and_clean_views():
    st = _state(5, opacity=0.5)
    st.params["opacity_logits"][0] = _logit(0.001)
    D.reset_opacity(st, 0.01)
    o = 1 / (1 + np.exp(-st.params["opacity_logits"].astype(np.float64)))
    np.testing.assert_allclose(o, [0.001, 0.01, 0.01, 0.01, 0.01], rtol=1e-5)
    assert np.all(st.adam.exp_avg["opacity_logits"] == 0) and np.all(st.adam.exp_avg["means"] == 1)
    vis = np.array([[True, False, False, False, False], [False, False, True, False, False]])
    st.params["means"][:, 0] = np.arange(5)
    assert D.clean_views(st, vis) == 3
    np.testing.assert_array_equal(st.params["means"][:, 0], [0, 2])
    assert st.stats[D.ACCUM].shape == (2,) and st.adam.exp_avg["means"].shape == (2, 3)
    with pytest.raises(ValueError):
        D.clean_views(st, np.ones(3, bool))


def test_schedule():
    st = _state(3, opacity=0.5)
    cfg = preset("3dgs").densify
    rng = np.random.default_rng(0)
    assert D.maybe_densify(st, cfg, 500, 1.0, rng) is None  # only after densify_from
    assert D.maybe_densify(st, cfg, 550, 1.0, rng) is None
    assert D.maybe_densify(st, cfg, 600, 1.0, rng)["n"] == 3
    assert D.maybe_densify(st, cfg, 3000, 1.0, rng)["opacity_reset"]
    assert D.maybe_densify(st, cfg, 15000, 1.0, rng) is None
    dng = preset("dngaussian").densify
    st = _state(3, opacity=0.5)
    assert D.maybe_densify(st, dng, 3000, 1.0, rng) == {"cloned": 0, "split": 0, "pruned": 0, "n": 3}
    assert D.maybe_densify(st, dng, 6000, 1.0, rng) is None


def test_densify_on_a_state_without_statistics():
    """maybe_densify / densify_and_prune on a TrainState that never had statistics: they start at
    zero (nothing is a candidate), and the state comes out with them."""
    from reings.state import TrainState
    from reings.train import gaussians_from_points

    rng = np.random.default_rng(0)
    g = gaussians_from_points(rng.uniform(-1, 1, (30, 3)).astype(np.float32), None, 0, rng)
    cfg = preset("3dgs").densify  # densification due at iteration 600
    for f in (lambda st: D.maybe_densify(st, cfg, 600, 1.0, rng), lambda st: D.densify_and_prune(st, CFG, 1.0, rng)):
        st = TrainState.from_gaussians(g)
        assert D.ACCUM not in st.stats
        out = f(st)
        assert out["cloned"] == out["split"] == 0 and out["n"] == len(st)
        assert set(st.stats) == {D.ACCUM, D.COUNT, D.RADII} and all(len(v) == len(st) for v in st.stats.values())
