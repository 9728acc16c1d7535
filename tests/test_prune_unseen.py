"""Pruning the Gaussians no training pixel blends (DensifyConfig.prune_unseen; docs/method.md §11).

Checked:
  - the seen mask (`rendering.gaussian_importance` > 0, the rule's test) on analytic cases (camera at the origin looking down +z): a Gaussian in
    front is seen; one behind the camera, one far outside the frustum, one of opacity below
    1/255 and one behind two opaque layers (T < T_MIN there) are not; the mask of this device
    equals the float64 reference's, and both equal an independent brute-force evaluation of
    alpha and transmittance over every pixel (numpy, no rasterizer);
  - `prune_unseen` removes exactly the unseen ones, keeps parameters and moments aligned and
    never empties the model;
  - in a fit: the device engine against the host engine (bit for bit on PoCL), the densify
    record's counts, a resume from a checkpoint, and the option off never renders for it;
  - the options: RunConfig reaches the reings fits only; the resume settings.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import (assert_resumes_bit_identically, assert_same_state, dngaussian_fit_case, fit_case, make_camera,
                   make_gaussians)

W, H = 48, 32
T_MIN = 1e-4  # the rasterizer's stop (kernels/common.h), restated independently
ALPHA_MIN, ALPHA_MAX = 1.0 / 255.0, 0.99


def _cases():
    """(Gaussians, expected seen mask): the camera at the origin, looking down +z."""
    big = np.log(50.0)  # walls that cover the whole image at alpha ~0.98 (z = 3, 3.1, 3.2)
    means = [[0.0, 0.0, 2.0],    # 0 in front, between the camera and the walls: seen
             [0.0, 0.0, -2.0],   # 1 behind the camera
             [40.0, 0.0, 2.0],   # 2 far outside the frustum
             [0.3, 0.2, 2.5],    # 3 opacity below 1/255
             [0.0, 0.0, 3.0],    # 4 first wall: seen (T = 0.02 behind it)
             [0.0, 0.0, 3.1],    # 5 second wall: seen (T = 4e-4 behind it)
             [0.1, -0.1, 4.0],   # 6 behind the walls: every pixel has stopped (T_MIN)
             [0.0, 0.0, 3.2]]    # 7 third wall: T (1 - alpha) = 8e-6 < T_MIN, the pixels stop before it
    n = len(means)
    log_scales = np.full((n, 3), np.log(0.1))
    for i in (4, 5, 7):
        log_scales[i] = [big, big, np.log(0.01)]
    logits = np.full(n, 2.0)
    logits[3] = np.log(0.002 / 0.998)
    logits[[4, 5, 7]] = np.log(0.98 / 0.02)
    g = make_gaussians(means, log_scales=log_scales, opacity_logits=logits)
    return g, np.array([True, False, False, False, True, True, False, False])


def _brute_force_seen(g, cam) -> np.ndarray:
    """alpha*T > 0 somewhere, by evaluating every Gaussian at every pixel centre in float64 with
    the EWA projection written out here (pinhole, camera at the origin, identity rotation)."""
    from reings.types import SH_COUNTS  # noqa: F401  (same package, only for the array layout)

    K = cam.K
    n = len(g)
    ys, xs = np.mgrid[0:cam.height, 0:cam.width]
    px, py = xs + 0.5, ys + 0.5
    alphas, depths = [], []
    for i in range(n):
        t = g.means[i]
        if t[2] <= 0.01:
            alphas.append(np.zeros_like(px)); depths.append(np.inf)
            continue
        q = g.quats[i] / np.linalg.norm(g.quats[i])
        w_, x_, y_, z_ = q
        R = np.array([[1 - 2 * (y_ * y_ + z_ * z_), 2 * (x_ * y_ - w_ * z_), 2 * (x_ * z_ + w_ * y_)],
                      [2 * (x_ * y_ + w_ * z_), 1 - 2 * (x_ * x_ + z_ * z_), 2 * (y_ * z_ - w_ * x_)],
                      [2 * (x_ * z_ - w_ * y_), 2 * (y_ * z_ + w_ * x_), 1 - 2 * (x_ * x_ + y_ * y_)]])
        S = np.diag(np.exp(g.log_scales[i]))
        cov3 = R @ S @ S @ R.T
        fx, fy = K[0, 0], K[1, 1]
        J = np.array([[fx / t[2], 0, -fx * t[0] / t[2] ** 2], [0, fy / t[2], -fy * t[1] / t[2] ** 2]])
        cov2 = J @ cov3 @ J.T + 0.3 * np.eye(2)
        u = fx * t[0] / t[2] + K[0, 2]
        v = fy * t[1] / t[2] + K[1, 2]
        inv = np.linalg.inv(cov2)
        dx, dy = u - px, v - py
        power = -0.5 * (inv[0, 0] * dx * dx + inv[1, 1] * dy * dy) - inv[0, 1] * dx * dy
        o = 1.0 / (1.0 + np.exp(-g.opacity_logits[i]))
        a = np.minimum(ALPHA_MAX, o * np.exp(power))
        a[(a < ALPHA_MIN) | (power > 0)] = 0.0
        alphas.append(a); depths.append(t[2])
    seen = np.zeros(n, bool)
    T = np.ones_like(px)
    for i in np.argsort(depths, kind="stable"):
        a = alphas[i]
        blend = (a > 0) & (T * (1 - a) >= T_MIN)
        seen[i] = bool(np.any(blend))
        T = np.where(blend, T * (1 - a), np.where(a > 0, 0.0, T))  # a stopped pixel stays stopped
    return seen


def seen_by(g, cameras, device):
    """The rule's mask: Omega_G over `cameras` > 0 (reings/train.py, DensifyConfig.prune_unseen)."""
    from reings.rendering import gaussian_importance

    return gaussian_importance(g, cameras, device, (0.0, 0.0, 0.0), 0.01) > 0.0


def test_seen_by_analytic_cases(device):
    g, want = _cases()
    cam = make_camera(W, H)
    brute = _brute_force_seen(g, cam)
    np.testing.assert_array_equal(brute, want)
    ref = seen_by(g, [cam], "reference")
    np.testing.assert_array_equal(ref, want)
    dev = seen_by(g, [cam], device)
    np.testing.assert_array_equal(dev, want)
    # two cameras: the union (the second camera turned around sees the one behind the first)
    back = make_camera(W, H, viewmat=np.diag([-1.0, 1.0, -1.0, 1.0]))
    two = seen_by(g, [cam, back], device)
    np.testing.assert_array_equal(two, want | _brute_force_seen_turned(g, back))


def _brute_force_seen_turned(g, cam):
    """The brute force of a camera rotated 180 degrees about y: world (x, y, z) -> (-x, y, -z)."""
    from reings.types import Gaussians

    flip = np.diag([-1.0, 1.0, -1.0])
    q = g.quats
    # R_world->cam = flip; a Gaussian's rotation becomes flip @ R: the quaternion of flip is (0, 0, 1, 0)
    qf = np.stack([-q[:, 2], -q[:, 3], q[:, 0], q[:, 1]], axis=1)  # (0,0,1,0) * q
    g2 = Gaussians(g.means @ flip.T, qf, g.log_scales, g.opacity_logits, g.sh)
    return _brute_force_seen(g2, make_camera(W, H))


def test_prune_unseen_keeps_the_seen_and_the_moments_aligned():
    from reings.densify import prune_unseen
    from reings.state import TrainState

    g, want = _cases()
    st = TrainState.from_gaussians(g)
    for k in st.params:
        st.adam.exp_avg[k][...] = np.arange(len(st))[(slice(None),) + (None,) * (st.params[k].ndim - 1)]
    means_before = st.params["means"].copy()
    assert prune_unseen(st, want) == int((~want).sum())
    assert len(st) == int(want.sum())
    np.testing.assert_array_equal(st.params["means"], means_before[want])
    for k in st.params:
        if st.params[k].size:  # sh_rest is [N, 0, 3] at degree 0
            np.testing.assert_array_equal(st.adam.exp_avg[k].reshape(len(st), -1)[:, 0], np.flatnonzero(want))
    assert prune_unseen(st, np.zeros(len(st), bool)) == 0 and len(st) == int(want.sum())  # never empty
    with pytest.raises(ValueError, match="prune_unseen"):
        prune_unseen(st, np.ones(len(st) + 1, bool))


# {{{ in a fit

@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    # a third of the initial points far behind the cameras' backs: nothing blends them
    init = replace(init, means=np.where((np.arange(len(init)) % 3 == 0)[:, None],
                                        init.means * [1, 1, -1] - [0, 0, 30], init.means))
    cfg = replace(cfg, densify=replace(cfg.densify, prune_unseen=True, clean_views=False, densify_from=5,
                                       densify_interval=5))
    return scene, init, cfg


def test_fit_prunes_the_unseen_device_matches_host(device, case):
    from reings.backends import get_backend
    from reings.backends.opencl import quirks

    host = fit_case(case, device, engine="host")
    dev = fit_case(case, device, engine="device")
    assert host.history.n_gaussians == dev.history.n_gaussians
    first = dev.history.densify[0][1]
    assert first["unseen"] >= 100, first  # the 100 put behind the cameras, at the first densification
    assert all("unseen" in d for _, d in dev.history.densify)
    exact = quirks.is_pocl(get_backend(device).handle.device)
    assert_same_state(host.state, dev.state, exact, "prune_unseen: device vs host")


def test_fit_with_prune_unseen_resumes_bit_identically(device, case, tmp_path):
    assert_resumes_bit_identically(case, device, tmp_path, stop_at=17)


@pytest.mark.parametrize("engine", ["device", "host"])
def test_off_never_renders_for_it_and_on_prunes(device, case, monkeypatch, engine):
    """Off: the importance renders (Trainer.importance) never run (the fit is the one without the
    option); on: they run once per densification, fewer Gaussians than off, and every densify
    record's n is the model's size after the pruning."""
    from reings.backends.host_trainer import HostTrainer
    from reings.backends.opencl.trainer import DeviceTrainer

    scene, init, cfg = case
    cls = DeviceTrainer if engine == "device" else HostTrainer
    orig = cls.importance
    monkeypatch.setattr(cls, "importance", lambda *a, **k: pytest.fail("rendered with the option off"))
    off = fit_case((scene, init, replace(cfg, densify=replace(cfg.densify, prune_unseen=False))), device,
                   engine=engine)
    assert all("unseen" not in d for _, d in off.history.densify)
    sizes = []

    def counted(tr, *a, **k):
        omega = orig(tr, *a, **k)
        sizes.append(len(omega))
        return omega

    monkeypatch.setattr(cls, "importance", counted)
    on = fit_case(case, device, engine=engine)
    assert len(on.state) < len(off.state)
    assert len(sizes) == len(on.history.densify)
    assert [d["n"] for _, d in on.history.densify] == [n - d["unseen"] for n, (_, d) in zip(sizes, on.history.densify)]


@pytest.mark.parametrize("engine", ["device", "host"])
def test_trainer_importance_is_gaussian_importance(device, engine):
    """Trainer.importance of an uploaded state (the densification's Omega_G, read on the device
    without uploading the Gaussians per view) equals rendering.gaussian_importance of the same
    Gaussians bit for bit, on the analytic cases and two cameras, and its mask is the brute force's."""
    from reings.backends import get_backend
    from reings.rendering import gaussian_importance
    from reings.state import TrainState

    g, want = _cases()
    cams = [make_camera(W, H), make_camera(W, H, viewmat=np.diag([-1.0, 1.0, -1.0, 1.0]))]
    st = TrainState.from_gaussians(g)
    tr = get_backend(device).trainer([np.zeros((H, W, 3), np.float32)] * 2, engine=engine)
    tr.upload(st)
    got = tr.importance(cams, (0.0, 0.0, 0.0), 0.01)
    ref = gaussian_importance(st.gaussians(0), cams, device, (0.0, 0.0, 0.0), 0.01)
    assert got.dtype == np.float64 and got.shape == (len(g),)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got[:len(want)] > 0, want | _brute_force_seen_turned(g, cams[1]))
# }}}


def test_run_config_reaches_the_reings_fits_only():
    """RunConfig.prune_unseen: none -> the family's (on for llff, off for dtu), explicit values win,
    never for the baselines; recorded in the resume settings only when on."""
    from reings.config import RunConfig
    from reings.pipeline import PRUNE_UNSEEN_BY_FAMILY, prune_unseen_of, run_settings

    assert PRUNE_UNSEEN_BY_FAMILY == {"llff": True, "dtu": False}
    default = RunConfig(method="reings")
    assert default.prune_unseen is None
    assert prune_unseen_of(default, "llff") and not prune_unseen_of(default, "dtu")
    assert run_settings(default.resolved(), "llff").get("prune_unseen") is True
    assert "prune_unseen" not in run_settings(default.resolved(), "dtu")
    off = RunConfig(method="reings", prune_unseen=False)
    assert not prune_unseen_of(off, "llff") and "prune_unseen" not in run_settings(off.resolved(), "llff")
    on = RunConfig(method="reings", prune_unseen=True)
    assert prune_unseen_of(on, "dtu") and run_settings(on.resolved(), "dtu").get("prune_unseen") is True
    base = RunConfig(method="dngaussian", prune_unseen=True)
    assert not prune_unseen_of(base, "llff") and "prune_unseen" not in run_settings(base.resolved(), "llff")


def test_cli_takes_both_forms_and_leaves_none_when_absent():
    from reings.cli import build_parser, config_from_args

    p = build_parser()
    for argv, want in ((["--prune-unseen"], True), (["--no-prune-unseen"], False), ([], None)):
        cfg = config_from_args(p.parse_args(["run", "--out", "o"] + argv))
        assert cfg.prune_unseen is want, argv


@pytest.mark.parametrize("method, family, kw, want", [
    ("reings", "llff", {}, True), ("reings", "dtu", {}, False), ("dngaussian", "llff", {}, False),
    ("reings", "llff", {"prune_unseen": False}, False), ("reings", "dtu", {"prune_unseen": True}, True),
    ("dngaussian", "llff", {"prune_unseen": True}, False)])
def test_the_fits_recipes_get_it(method, family, kw, want):
    from test_recipe_family import _ctx

    from reings.pipeline import baseline_recipe

    ctx, _ = _ctx(family, method=method, **kw)
    assert ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family)).densify.prune_unseen is want
