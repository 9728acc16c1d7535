"""LossConfig.view_warp_scale: the binocular view_warp term at 1/2 resolution (docs/binocular.md §4.5).

Checked against independent references:
  - `Trainer.view_warp(..., scale=2)` of both engines (and the host engine on the float64 reference
    backend) against the float64 composition of the twins: the training render's depth and the
    training image block-averaged (reference_block_mean.block_mean_fwd), the term
    (reference_view_warp.view_warp_fwd_bwd) with the focal fx / 2 on the virtual view rendered at 1/2,
    the depth cotangent spread back by the pooling's adjoint (block_mean_bwd); odd sizes, so a row and
    a column are dropped (their depth cotangent exactly 0);
  - a short fit with the term at scale 2: the virtual view is rendered at the half size (a spy on the
    trainers' forwards), the two engines agree (bit for bit on PoCL, tests/cases.py
    `assert_engines_agree`), with DropGaussian and the shared soft depth term too, the sync-free
    binning gives the same bits as the sync one, a resumed fit is bit-identical, and the fit differs
    from scale 1;
  - the refusals, and `train.programs_of` (the device engine's block mean built before the fit's clock).

Tolerances: V_ATOL_REL, V_RTOL as tests/test_view_warp.py (float32 kernels against the float64 twin);
the composition's discrete decisions (floor of the disparity, validity, signs) are those of the
float32-pooled inputs (checked first: otherwise the comparison would measure a flipped decision).
"""
from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from asserts import assert_close
from cases import (assert_engines_agree, assert_resumes_bit_identically, assert_same_state, binning,
                   dngaussian_fit_case, fit_case)
from reings.backends import get_backend
from reings.backends import reference_block_mean as B
from reings.backends.opencl import quirks
from reings.backends.reference_view_warp import view_warp_fwd_bwd, view_warp_pattern, view_warp_state, virtual_camera
from reings.state import TrainState
from reings.train import depth_pass_camera, fit, programs_of
from reings.types import Gaussians

V_ATOL_REL, V_RTOL = 1e-5, 1e-5  # tests/test_view_warp.py's: float32 gradients vs the float64 twin
LOSS_RTOL = 1e-5


# {{{ the term against the float64 composition

def _tiny_scene(width=41, height=31):
    """24 opaque-ish Gaussians in front of the procedural scene's first camera, odd image sizes."""
    import reings

    scene = reings.make_procedural_scene(n_views=2, width=width, height=height, supersample=1)
    cam = scene.cameras[0]
    rng = np.random.default_rng(3)
    fwd, right, up = cam.viewmat[2, :3], cam.viewmat[0, :3], cam.viewmat[1, :3]
    pts = (cam.center + fwd * rng.uniform(3.0, 4.0, (24, 1)) + right * rng.uniform(-1, 1, (24, 1))
           + up * rng.uniform(-0.8, 0.8, (24, 1)))
    g = Gaussians(pts.astype(np.float32), np.tile(np.array([1, 0, 0, 0], np.float32), (24, 1)),
                  np.full((24, 3), np.log(0.25), np.float32), rng.uniform(0.5, 2.0, 24).astype(np.float32),
                  rng.normal(0, 0.6, (24, 1, 3)).astype(np.float32))
    return g, cam, np.asarray(scene.images[0], np.float32)


def _host(tr, x, shape):
    """A trainer's image or cotangent (a device buffer or a host array) as a host float32 array."""
    if isinstance(x, np.ndarray):
        return np.asarray(x, np.float32)
    return tr._read(x, shape, np.float32)


def _check_composition(device: str, engine: str, b: float = 0.35):
    g, cam, gt = _tiny_scene()
    tr = get_backend(device).trainer([gt], engine=engine)
    tr.upload(TrainState.from_gaussians(g, 0))
    virt = tr.forward(depth_pass_camera(virtual_camera(cam, b), 2), 1, (0, 0, 0), 0.01, keep=True)
    fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
    assert (virt.width, virt.height, fr.width, fr.height) == (20, 15, 41, 31)
    v_virt, v_depth = tr.view_warp(virt, fr, 0, b, 1.0, 0.05, 2)
    stats = tr.read_view_warp()
    v_virt, v_depth = _host(tr, v_virt, (15, 20, 3)), _host(tr, v_depth, (31, 41))
    rgb = np.asarray(tr.read_rgb(virt), np.float32)
    depth = np.asarray(fr.out.depth if hasattr(fr, "out") else tr.read_depth(fr), np.float32)
    # the float64 composition: pool (block_mean_fwd), the term at fx / 2, the pooling's adjoint
    dp, gp, fx = B.block_mean_fwd(depth, 2), B.block_mean_fwd(gt, 2), cam.fx / 2
    np.testing.assert_array_equal(view_warp_pattern(rgb, dp, gp, fx, b),
                                  view_warp_pattern(rgb, B.block_mean_f32(depth, 2), B.block_mean_f32(gt, 2), fx, b),
                                  err_msg="a discrete decision of the term flips with float32 pooling: redraw the case")
    loss, want_virt, want_dp = view_warp_fwd_bwd(rgb, dp, gp, fx, b, 1.0, 0.05)
    want_depth = B.block_mean_bwd(want_dp, 2, depth.shape)
    valid = view_warp_state(rgb, dp, gp, fx, b).valid
    assert 0.2 < valid.mean() < 1 and np.abs(want_virt).max() > 0 and np.abs(want_dp).max() > 0  # informative
    what = f"{device} {engine}"
    assert_close(v_virt, want_virt, atol=V_ATOL_REL * np.abs(want_virt).max(), rtol=V_RTOL, name=f"{what} v_virt")
    assert_close(v_depth, want_depth, atol=V_ATOL_REL * np.abs(want_depth).max(), rtol=V_RTOL, name=f"{what} v_depth")
    assert not v_depth[30].any() and not v_depth[:, 40].any()  # the dropped row and column: exactly 0
    assert abs(stats["loss"] - loss) <= LOSS_RTOL * loss, (what, stats["loss"], loss)
    assert abs(stats["valid_fraction"] - valid.mean()) < 1e-12, what
    # the term at full resolution is another one (the test can tell the scales apart)
    full = view_warp_fwd_bwd(rgb, dp, gp, cam.fx, b, 1.0, 0.05)
    assert abs(full[0] - loss) > 1e-3 * loss


@pytest.mark.parametrize("engine", ["host", "device"])
def test_the_term_at_scale_2_is_the_float64_composition(device, engine):
    _check_composition(device, engine)


def test_the_term_at_scale_2_on_the_reference_backend():
    _check_composition("reference", "host")


def test_the_trainers_refuse_a_virtual_frame_of_another_size(device):
    g, cam, gt = _tiny_scene()
    for engine in ("host", "device"):
        tr = get_backend(device).trainer([gt], engine=engine)
        tr.upload(TrainState.from_gaussians(g, 0))
        virt = tr.forward(virtual_camera(cam, 0.3), 1, (0, 0, 0), 0.01, keep=True)  # full size
        fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
        with pytest.raises(ValueError, match="must be 20x15"):
            tr.view_warp(virt, fr, 0, 0.3, 1.0, 0.05, 2)
        for bad in (3, 0, 1.5):
            with pytest.raises(ValueError, match="scale must be 1 or 2"):
                tr.view_warp(virt, fr, 0, 0.3, 1.0, 0.05, bad)
# }}}


# {{{ the fit

@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=65, height=49, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=12, view_warp_baseline=0.3,
                                    view_warp_scale=2),
                  densify=replace(cfg.densify, opacity_decay=0.99, opacity_decay_from=5))
    return scene, init, cfg


_RUNS: dict = {}


def _run(case, device, engine, variant="plain", **loss):
    """fit_case of `case` with LossConfig overrides, on `engine`; the (width, height, fx, keep) of every
    forward of the fit (spied on both trainers). Cached per arguments (the module's fits are shared)."""
    from reings.backends.host_trainer import HostTrainer
    from reings.backends.opencl.trainer import DeviceTrainer

    key = (device, engine, variant, tuple(sorted(loss.items())))
    if key not in _RUNS:
        scene, init, cfg = case
        seen = []
        with pytest.MonkeyPatch.context() as mp:
            for cls in (DeviceTrainer, HostTrainer):
                def spy(self, cam, *a, _forward=cls.forward, keep=False, **k):
                    seen.append((cam.width, cam.height, cam.fx, keep))
                    return _forward(self, cam, *a, keep=keep, **k)

                mp.setattr(cls, "forward", spy)
            c = (scene, init, replace(cfg, loss=replace(cfg.loss, **loss)))
            if variant == "plain":
                r = fit_case(c, device, engine=engine)
            else:  # the binning mode `variant` ("sync", "async")
                with binning(get_backend(device), variant):
                    r = fit_case(c, device, engine=engine)
        _RUNS[key] = (r, seen)
    return _RUNS[key]


@pytest.mark.parametrize("loss", [{}, {"drop_gamma": 0.2, "soft_depth_shared": True}], ids=["plain", "drop-soft"])
def test_the_engines_agree_at_scale_2(device, case, loss):
    (host, seen_h), (dev, seen_d) = (_run(case, device, e, **loss) for e in ("host", "device"))
    exact = quirks.is_pocl(get_backend(device).handle.device)
    assert_engines_agree(device, host.state, dev.state, f"view_warp_scale 2 {loss}")
    assert_same_state(host.state, dev.state, exact, f"view_warp_scale 2 {loss}")
    assert host.history.n_gaussians == dev.history.n_gaussians
    if exact:
        # the states are the same bytes (above); the logged losses are float64 host sums of the same device values,
        # formed by each engine's own code, whose last bit can differ between machines (equal on session 46's Xeon,
        # 1 ulp apart in one entry on a Zen 3 EPYC, session 47, with session 46's code too): a few ulps
        np.testing.assert_allclose(host.history.loss, dev.history.loss, rtol=4 * np.finfo(np.float64).eps, atol=0)
        hv, dv = (np.asarray([tuple(x) for x in h.history.view_warp], np.float64) for h in (host, dev))
        np.testing.assert_allclose(hv, dv, rtol=4 * np.finfo(np.float64).eps, atol=0)
    assert dev.history.view_warp and all(0.2 < v < 1 for _, _, v in dev.history.view_warp)
    scene, _, cfg = case
    fxs = {cam.fx for cam in scene.cameras}
    for seen in (seen_h, seen_d):
        kept = [s for s in seen if s[3]]
        assert len(kept) == cfg.iterations - cfg.loss.view_warp_from + 1  # one virtual view per iteration
        assert all((w, h) == (32, 24) and 2 * fx in fxs for w, h, fx, _ in kept)  # at 1/2: 65 // 2 x 49 // 2
        assert all((w, h) == (65, 49) for w, h, _, keep in seen if not keep)  # every other render full size


def test_the_sync_free_binning_gives_the_same_bits_at_scale_2(device, case):
    """The half-size kept frame (slot 1) beside full-size frames in slot 0, binned sync-free against in sync,
    with DropGaussian and the shared soft depth term: the same state and histories."""
    loss = {"drop_gamma": 0.2, "soft_depth_shared": True}
    a, _ = _run(case, device, "device", "sync", **loss)
    b, _ = _run(case, device, "device", "async", **loss)
    assert_same_state(a.state, b.state, True, "view_warp_scale 2: sync-free vs sync binning")
    assert a.history.loss == b.history.loss and a.history.view_warp == b.history.view_warp


def test_the_scale_changes_the_fit(device, case):
    half, seen_half = _run(case, device, "device")
    full, seen_full = _run(case, device, "device", view_warp_scale=1)
    assert all((w, h) == (65, 49) for w, h, _, _ in seen_full)
    assert not np.array_equal(full.state.params["means"], half.state.params["means"])
    it = case[2].loss.view_warp_from
    # before the term starts the fits are the same (the scale touches nothing else)
    assert [x for i, x in zip(full.history.iteration, full.history.loss) if i < it] == \
           [x for i, x in zip(half.history.iteration, half.history.loss) if i < it]


def test_the_fit_resumes_bit_identically_at_scale_2(device, case, tmp_path):
    """Stopped at 17, last checkpoint at 15: inside the term's span (the pooled training images are made
    anew by the resumed fit's trainer)."""
    ref, res = assert_resumes_bit_identically(case, device, tmp_path, stop_at=17)
    assert [tuple(x) for x in res.history.view_warp] == [tuple(x) for x in ref.history.view_warp]


def test_refusals_and_programs(case):
    from reings.config import LossConfig, check_value

    scene, init, cfg = case
    for bad in (3, 4, 0):
        with pytest.raises(ValueError, match="view_warp_scale must be 1 or 2"):
            fit(scene, replace(cfg, loss=replace(cfg.loss, view_warp_scale=bad)), device="reference", init=init)
        f = next(f for f in fields(LossConfig) if f.name == "view_warp_scale")
        assert check_value(f, bad) == f"must be 1 or 2, got {bad}"
    assert check_value(f, 2) is None and LossConfig().view_warp_scale == 1
    assert programs_of(cfg, 1, True, "device")["block_mean"]
    assert not programs_of(cfg, 1, True, "host")["block_mean"]  # the host engine pools in numpy
    assert not programs_of(replace(cfg, loss=replace(cfg.loss, view_warp_scale=1)), 1, True)["block_mean"]
    assert not programs_of(replace(cfg, loss=replace(cfg.loss, view_warp_weight=0.0)), 1, True)["block_mean"]
# }}}
