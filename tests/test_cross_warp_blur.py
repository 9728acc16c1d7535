"""The cross_warp term's blur levels (LossConfig.cross_warp_blur, RunConfig.cross_warp_blur;
reference_cross_warp.blur_image; the level loop of train._Iteration.photometric_pass;
docs/method.md §12): the blur against scipy and a direct 2-D convolution written here, the
trainers' levels against the kernel run on the blurred images themselves (the weight split, the
accumulation, the loss summed over the levels), device against host, central differences of the
multi-level loss through the float64 twin, the fit without levels unchanged (same calls, same
launches, same bits), a fit with levels (engines agree, one blur per view and sigma), and the
option from the command line to the fits, the settings, resume and `reings eval`."""
from __future__ import annotations

import json
import math
import types
from dataclasses import replace

import numpy as np
import pytest

from cases import assert_engines_agree, device_depth_frame, dngaussian_fit_case, fit_case, make_camera, rotation_viewmat
from reings.backends import get_backend
from reings.backends.opencl import quirks
from reings.backends.reference_cross_warp import blur_image, cross_warp_fwd_bwd
from reings.types import Camera

NEAR = 0.01


def _moved(cam: Camera, angles=(0.0, 0.0, 0.0), centre_shift=(0.0, 0.0, 0.0)) -> Camera:
    r = rotation_viewmat(angles, (0, 0, 0))[:3, :3] @ cam.viewmat[:3, :3]
    c = cam.center + np.asarray(centre_shift, np.float64)
    v = np.eye(4)
    v[:3, :3], v[:3, 3] = r, -r @ c
    return Camera(cam.K.copy(), v, cam.width, cam.height)


def _exact(device) -> bool:
    return quirks.is_pocl(get_backend(device).handle.device)


# {{{ the blur

def _reflect101(i: int, n: int) -> int:
    """Index i folded into [0, n) by mirroring about the edge samples (no repeat), as often as
    needed; a one-sample axis repeats its sample."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * (n - 1) - i
    return i


def _blur_direct(img, sigma):
    """A direct 2-D convolution with the outer product of the normalised 1-D Gaussian, float64,
    borders by explicit reflect-101 index folding (one loop per output pixel and tap)."""
    a = np.asarray(img, np.float64)
    h, w = a.shape[:2]
    r = math.ceil(3 * sigma)
    k1 = np.array([math.exp(-x * x / (2 * sigma * sigma)) for x in range(-r, r + 1)])
    k1 /= k1.sum()
    out = np.zeros_like(a)
    for y in range(h):
        for x in range(w):
            acc = np.zeros(a.shape[2:])
            for dy in range(-r, r + 1):
                yy = _reflect101(y + dy, h)
                for dx in range(-r, r + 1):
                    acc += k1[dy + r] * k1[dx + r] * a[yy, _reflect101(x + dx, w)]
            out[y, x] = acc
    return out


@pytest.mark.parametrize("sigma", [0.4, 1.0, 1.5, 2.0, 3.7])
def test_blur_matches_direct_convolution_and_scipy(sigma):
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(int(sigma * 10))
    img = rng.uniform(0, 1, (9, 13, 3)).astype(np.float32)  # radius 12 at 3.7: folded more than once
    got = blur_image(img, sigma)
    assert got.dtype == np.float32 and got.shape == img.shape
    want = _blur_direct(img, sigma)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    # scipy: mode 'mirror' is reflect-101; its radius is given (its truncate rounds, ours is ceil(3 sigma))
    sp = np.stack([gaussian_filter(img[..., c].astype(np.float64), sigma, mode="mirror", radius=math.ceil(3 * sigma))
                   for c in range(3)], -1)
    np.testing.assert_allclose(got, sp, rtol=0, atol=1e-6)
    # a 2-D image works the same
    np.testing.assert_allclose(blur_image(img[..., 0], sigma), want[..., 0], rtol=0, atol=1e-6)


def test_blur_constant_identity_and_refusals():
    c = np.full((6, 7, 3), 0.3712, np.float32)
    for s in (0.5, 2.0, 9.0):
        np.testing.assert_allclose(blur_image(c, s), c, rtol=0, atol=1e-7)
    img = np.random.default_rng(0).uniform(0, 1, (5, 5, 3)).astype(np.float32)
    assert blur_image(img, 0.0) is img and blur_image(img, 0) is img
    one = np.random.default_rng(1).uniform(0, 1, (1, 8, 3)).astype(np.float32)  # a one-row image: rows repeat
    np.testing.assert_allclose(blur_image(one, 1.0), _blur_direct(one, 1.0), rtol=0, atol=1e-6)
    b = blur_image(img, 1.0)
    assert not np.array_equal(b, img) and abs(float(b.mean()) - float(img.mean())) < 0.05
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sigma"):
            blur_image(img, bad)
# }}}


# {{{ the trainers' levels

def _maps(seed, h, w):
    rng = np.random.default_rng(seed)
    d0 = rng.uniform(1.5, 4.0, (h, w)).astype(np.float32)
    a = rng.uniform(0.3, 1.0, (h, w)).astype(np.float32)
    d = (d0 * a).astype(np.float32)
    ii = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    return d, a, ii, ij


def _cams(h, w):
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    return ci, _moved(ci, angles=(0.02, 0.05, -0.03), centre_shift=(0.4, -0.1, 0.05))


def _device_levels(device, d, a, images, ci, cj, weight, sigmas, tol=0.0, partner=None):
    """The device trainer's calls of the engine's level loop on these maps: (dL/dD, read_cross_warp())."""
    tr = get_backend(device).trainer(images, engine="device")
    held = None if partner is None else tr.hold_depth(device_depth_frame(tr, cj, *partner))
    fr, v = device_depth_frame(tr, ci, d, a), None
    levels = (0.0, *sigmas)
    for s in levels:
        v = tr.cross_warp(fr, 0, 1, cj, weight / len(levels), NEAR, into=v, occlusion=tol, partner_depth=held, sigma=s)
    return tr._read(v, d.shape, np.float32), tr.read_cross_warp()


def _host_levels(d, a, images, ci, cj, weight, sigmas, tol=0.0, partner=None):
    tr = get_backend("reference").trainer(images, engine="host")

    def frame(cam, dd, aa):
        return types.SimpleNamespace(width=cam.width, height=cam.height, cam=cam,
                                     out=types.SimpleNamespace(depth=dd, alpha=aa))

    held = None if partner is None else tr.hold_depth(frame(cj, *partner))
    fr, v = frame(ci, d, a), None
    levels = (0.0, *sigmas)
    for s in levels:
        v = tr.cross_warp(fr, 0, 1, cj, weight / len(levels), NEAR, into=v, occlusion=tol, partner_depth=held, sigma=s)
    return v, tr.read_cross_warp()


@pytest.mark.parametrize("tol", [0.0, 0.03])
def test_levels_are_the_kernel_on_the_blurred_images(device, tol):
    """The levels of one frame: their sum is the sharp call plus the kernel run on trainers whose
    training images ARE the blurred images (each with weight w / 3), accumulated in that order;
    the loss is the sum of those calls' losses, the fractions the sharp level's; the host trainer
    gives the same bits on PoCL (and the same loss and fractions)."""
    h, w = 23, 31
    d, a, ii, ij = _maps(4, h, w)
    ci, cj = _cams(h, w)
    rng = np.random.default_rng(9)
    aj = rng.uniform(0.3, 1, (h, w)).astype(np.float32)
    partner = (aj * rng.uniform(1.0, 4.5, (h, w))).astype(np.float32), aj
    kw = dict(tol=tol, partner=partner if tol else None)
    sig = (2.0, 4.0)
    got, st = _device_levels(device, d, a, [ii, ij], ci, cj, 0.6, sig, **kw)
    parts = [_device_levels(device, d, a, [blur_image(ii, s), blur_image(ij, s)], ci, cj, 0.6 / 3, (), **kw)
             for s in (0.0, *sig)]  # one level each, of the levels' weight
    want = parts[0][0] + parts[1][0]
    want = want + parts[2][0]
    np.testing.assert_array_equal(got, want)
    assert st["loss"] == parts[0][1]["loss"] + parts[1][1]["loss"] + parts[2][1]["loss"]
    assert st["valid_fraction"] == parts[0][1]["valid_fraction"] > 0.2
    assert st["occluded_fraction"] == parts[0][1]["occluded_fraction"]
    assert (st["occluded_fraction"] > 0.05) == bool(tol)
    # each level pulls differently: the blurred ones are not the sharp one again
    assert not np.array_equal(parts[1][0], parts[0][0]) and not np.array_equal(parts[2][0], parts[1][0])
    sharp, _ = _device_levels(device, d, a, [ii, ij], ci, cj, 0.6, (), **kw)
    assert not np.allclose(got, sharp)
    host, hst = _host_levels(d, a, [ii, ij], ci, cj, 0.6, sig, **kw)
    if _exact(device):
        np.testing.assert_array_equal(got, host)
    else:
        np.testing.assert_allclose(got, host, rtol=1e-5, atol=1e-6 * np.abs(host).max())
    assert hst["valid_fraction"] == st["valid_fraction"] and hst["occluded_fraction"] == st["occluded_fraction"]
    assert hst["loss"] == pytest.approx(st["loss"], rel=1e-6)
    hparts = [_host_levels(d, a, [blur_image(ii, s), blur_image(ij, s)], ci, cj, 0.6 / 3, (), **kw)[1]["loss"]
              for s in (0.0, *sig)]
    assert hst["loss"] == hparts[0] + hparts[1] + hparts[2]


def test_the_loss_restarts_at_each_forward():
    """read_cross_warp sums the calls since the last forward only: a forward between two calls
    leaves the second alone (the host trainer's own forward, on a real state)."""
    import reings
    from reings.state import TrainState
    from cases import gaussians_before

    scene = reings.make_procedural_scene(n_views=2, width=24, height=20, supersample=1)
    cam, cam2 = scene.cameras
    g = gaussians_before(cam, np.random.default_rng(2), 14, opacity=(1, 3))
    tr = get_backend("reference").trainer(list(scene.images), engine="host")
    tr.upload(TrainState.from_gaussians(g, 0))
    fr = tr.forward(cam, 1, (0, 0, 0), NEAR)
    tr.cross_warp(fr, 0, 1, cam2, 1.0, NEAR)
    one = tr.read_cross_warp()["loss"]
    tr.cross_warp(fr, 0, 1, cam2, 1.0, NEAR, sigma=2.0)
    two = tr.read_cross_warp()["loss"]
    assert one > 0 and two > one
    fr = tr.forward(cam, 1, (0, 0, 0), NEAR)
    tr.cross_warp(fr, 0, 1, cam2, 1.0, NEAR)
    assert tr.read_cross_warp()["loss"] == one
    fr = tr.forward(cam, 1, (0, 0, 0), NEAR)
    with pytest.raises(RuntimeError, match="before a cross_warp"):
        tr.read_cross_warp()


def test_multilevel_gradient_fd(device):
    """Central differences of the multi-level loss (the float64 twin summed over the levels, on
    the same float32 blurred images, each of weight w / 3) along random directions of the rendered
    depth, against the twin's summed gradient (tight) and against the device trainer's
    accumulated cotangent (float32, loose: the odd pixel whose float32 position rounds across a
    cell edge)."""
    h, w = 14, 18
    d, a, ii, ij = _maps(3, h, w)
    d, a = d.astype(np.float64), a.astype(np.float64)
    ci, cj = _cams(h, w)
    sig, wt = (1.5, 3.0), 0.7
    levels = [(blur_image(ii, s), blur_image(ij, s)) for s in (0.0, *sig)]

    def total(dd):
        out = [cross_warp_fwd_bwd(dd, a, bi, bj, ci, cj, wt / 3, NEAR) for bi, bj in levels]
        return sum(o[0] for o in out), sum(o[1] for o in out), out[0][2]

    loss, g, ok = total(d)
    assert ok.sum() > 0.3 * h * w and np.abs(g[ok]).max() > 0
    dev, st = _device_levels(device, d.astype(np.float32), a.astype(np.float32), [ii, ij], ci, cj, wt, sig)
    assert st["loss"] == pytest.approx(loss, rel=1e-3)
    rng = np.random.default_rng(8)
    e = 1e-7
    for trial in range(5):
        v = rng.normal(size=(h, w))
        fd = (total(d + e * v)[0] - total(d - e * v)[0]) / (2 * e)
        assert fd == pytest.approx(float(np.sum(g * v)), rel=1e-5, abs=1e-10), trial
        assert fd == pytest.approx(float(np.sum(dev.astype(np.float64) * v)), rel=2e-2), trial
    # the sharp level alone is not the multi-level loss's gradient: the check can tell
    g0 = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, wt, NEAR)[1]
    assert abs(float(np.sum(g0 * v)) - fd) > 0.05 * abs(fd)
# }}}


# {{{ in the fit

@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=21,
                                           soft_depth_from=3, densify_until=25)
    return scene, init, replace(cfg, loss=replace(cfg.loss, cross_warp=0.5, cross_warp_from=3))


def _blurred(case, sigmas):
    scene, init, cfg = case
    return scene, init, replace(cfg, loss=replace(cfg.loss, cross_warp_blur=tuple(sigmas)))


def _recording(monkeypatch, cls):
    """Records each cross_warp call's (weight, sigma) and each kernel launch's stage name."""
    calls, stages = [], []
    cw, launch = cls.cross_warp, getattr(cls, "_launch", None)

    def rec(self, fr, view, partner, partner_cam, weight, near, **k):
        calls.append((weight, k.get("sigma", 0.0)))
        return cw(self, fr, view, partner, partner_cam, weight, near, **k)

    monkeypatch.setattr(cls, "cross_warp", rec)
    if launch is not None:
        def counting(self, stage, *a):
            stages.append(stage)
            return launch(self, stage, *a)

        monkeypatch.setattr(cls, "_launch", counting)
    return calls, stages


def test_no_levels_is_the_fit_of_before(device, case, monkeypatch):
    """cross_warp_blur absent and () are one config; its fit calls the term once per iteration of
    the term, with the full weight and sigma 0, launches cross_warp_grad once per iteration and
    cross_warp_rows once per logging iteration (as before the option), and never blurs."""
    from reings.backends import reference_cross_warp as R
    from reings.backends.opencl.trainer import DeviceTrainer

    scene, init, cfg = case
    assert cfg.loss.cross_warp_blur == ()
    explicit = _blurred(case, ())
    assert explicit[2] == cfg
    import reings.backends.opencl.trainer as T

    blurs = []
    orig_blur = R.blur_image
    for mod in (R, T):
        monkeypatch.setattr(mod, "blur_image", lambda *a: blurs.append(a) or orig_blur(*a))
    calls, stages = _recording(monkeypatch, DeviceTrainer)
    ref = fit_case(case, device, engine="device")
    n_ref = (len(calls), stages.count("cross_warp"), stages.count("cross_warp_rows"))
    span = cfg.iterations - cfg.loss.cross_warp_from + 1
    assert n_ref == (span, span, len(ref.history.cross_warp)) and len(ref.history.cross_warp) == 5
    assert set(calls) == {(0.5, 0.0)} and not blurs
    calls.clear()
    stages.clear()
    again = fit_case(explicit, device, engine="device")
    assert (len(calls), stages.count("cross_warp"), stages.count("cross_warp_rows")) == n_ref
    for k in ref.state.params:
        np.testing.assert_array_equal(again.state.params[k], ref.state.params[k], err_msg=k)
    assert [tuple(x) for x in again.history.cross_warp] == [tuple(x) for x in ref.history.cross_warp]
    assert again.history.loss == ref.history.loss


def test_fit_with_levels(device, case, monkeypatch):
    """Levels (2, 4): three calls per iteration of the term (sharp first, each of weight w / 3),
    three gradient launches each and three row launches per logging iteration; one blur per
    (view, sigma) used over the fit; the host engine gives the same fit (bit for bit on PoCL) and
    history; the result differs from the fit without levels."""
    import reings.backends.opencl.trainer as T
    from reings.backends import reference_cross_warp as R
    from reings.backends.host_trainer import HostTrainer

    blurred = _blurred(case, (2.0, 4.0))
    cfg = blurred[2]
    span = cfg.iterations - cfg.loss.cross_warp_from + 1
    blurs = []
    orig_blur = R.blur_image

    def counted(img, sigma):
        blurs.append(sigma)
        return orig_blur(img, sigma)

    monkeypatch.setattr(T, "blur_image", counted)
    calls, stages = _recording(monkeypatch, T.DeviceTrainer)
    dev = fit_case(blurred, device, engine="device")
    assert len(calls) == 3 * span
    for i in range(0, len(calls), 3):
        assert [s for _, s in calls[i:i + 3]] == [0.0, 2.0, 4.0]
        assert all(wt == 0.5 / 3 for wt, _ in calls[i:i + 3])
    assert stages.count("cross_warp") == 3 * span and stages.count("cross_warp_rows") == 3 * 5
    assert sorted(blurs) == [2.0] * 3 + [4.0] * 3  # 3 views, each sigma once
    monkeypatch.undo()
    blurs.clear()
    monkeypatch.setattr(R, "blur_image", counted)
    host = fit_case(blurred, device, engine="host")
    assert sorted(blurs) == [2.0] * 3 + [4.0] * 3
    assert [it for it, *_ in host.history.cross_warp] == [5, 10, 15, 20, 21]
    for (_, lh, vh), (_, ld, vd) in zip(host.history.cross_warp, dev.history.cross_warp):
        assert lh > 0 and 0 < vh <= 1
        np.testing.assert_allclose([ld, vd], [lh, vh], rtol=1e-5)
    assert_engines_agree(device, host.state, dev.state, "cross_warp blur")
    off = fit_case(case, device, engine="host")
    assert len(off.state) != len(host.state) or np.abs(off.state.params["means"] - host.state.params["means"]).max() > 0


def test_fit_with_levels_resumes_bit_identically(device, case, tmp_path):
    """Stopped at 17, last checkpoint at 15 (inside the term's span): the resumed fit's trainer makes
    its blurred images again, and the fit and its cross_warp history are the uninterrupted ones, bit
    for bit."""
    from cases import assert_resumes_bit_identically

    ref, res = assert_resumes_bit_identically(_blurred(case, (2.0, 4.0)), device, tmp_path, stop_at=17)
    assert ref.history.cross_warp
    assert [tuple(x) for x in res.history.cross_warp] == [tuple(x) for x in ref.history.cross_warp]


def test_fit_refuses_bad_levels(case):
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="cross_warp_blur"):
            fit_case(_blurred(case, (2.0, bad)), "reference")
# }}}


# {{{ the option

def test_option_parse_and_refusals(capsys):
    from reings.cli import build_parser, config_from_args
    from reings.config import LossConfig, RunConfig, parse_blur_sigmas

    def parse(*argv):
        return config_from_args(build_parser().parse_args(["run", *argv]))

    assert parse("--cross-warp-blur", "2,4").cross_warp_blur == (2.0, 4.0)
    assert parse("--cross-warp-blur", "1.5").cross_warp_blur == (1.5,)
    assert parse("--cross-warp-blur", "none").cross_warp_blur == ()
    assert parse().cross_warp_blur == () and RunConfig().cross_warp_blur == () and LossConfig().cross_warp_blur == ()
    assert parse_blur_sigmas(" 0.5 , 3 ") == (0.5, 3.0)
    for bad in ("2,-1", "nan", "2,inf", "a,2", "0,2", "0"):
        with pytest.raises(SystemExit):
            parse("--cross-warp-blur", bad)
        err = capsys.readouterr().err
        assert "--cross-warp-blur" in err, err
    for bad in ((-1.0,), (2.0, float("nan")), (float("inf"),), (0.0, 2.0)):
        with pytest.raises(ValueError, match="cross_warp_blur"):
            RunConfig(cross_warp_blur=bad)
    assert RunConfig(cross_warp_blur=[2, 4]).cross_warp_blur == (2.0, 4.0)


def test_toml_round_trip(tmp_path):
    from reings.config import RunConfig, load_run_config, to_toml

    for v in ((), (2.0, 4.0)):
        p = tmp_path / f"c{len(v)}.toml"
        p.write_text(to_toml(RunConfig(cross_warp_blur=v)))
        assert load_run_config(p).cross_warp_blur == v


def test_settings_recipe_and_notes():
    from reings.config import RunConfig
    from reings.evaluate import _ABSENT_WHEN_OFF, _setting_tag
    from reings.pipeline import RunContext, baseline_recipe, option_notes, run_settings

    s = run_settings(RunConfig(depth_prior="none").resolved(), "llff")
    assert s["cross_warp"] == 0.15 and "cross_warp_blur" not in s  # absent without levels (older folders resume)
    s = run_settings(RunConfig(depth_prior="none", cross_warp_blur=(2, 4)).resolved(), "llff")
    assert s["cross_warp_blur"] == [2.0, 4.0]
    assert "cross_warp_blur" not in run_settings(RunConfig(cross_warp_blur=(2,)).resolved(), "llff")  # term off
    assert "cross_warp_blur" in _ABSENT_WHEN_OFF
    tag = _setting_tag({"preset": "paper", "method": "reings", "depth_prior": "none", "config": s})
    assert "cross 0.15 blur 2,4" in tag
    for method, want in (("reings", (2.0, 4.0)), ("dngaussian", ())):
        cfg = RunConfig(method=method, depth_prior="none", cross_warp=0.2, view_warp=0.0, cross_warp_blur=(2, 4))
        ctx = RunContext.__new__(RunContext)
        ctx.cfg, ctx.family, ctx.smooth_w = cfg, "llff", None
        r = ctx.run_recipe(baseline_recipe("dngaussian", 100, 0))
        assert r.loss.cross_warp_blur == want, method
    ctx.cfg = RunConfig(depth_prior="none", view_warp=0.0)
    assert ctx.run_recipe(baseline_recipe("dngaussian", 100, 0)).loss.cross_warp_blur == ()
    assert option_notes(RunConfig(depth_prior="none", cross_warp=0, cross_warp_blur=(2,)), "llff", 3) == [
        "cross_warp_blur without cross_warp; ignored"]
    assert not option_notes(RunConfig(depth_prior="none", cross_warp_blur=(2,)), "llff", 3)


def test_resume_and_reuse_refuse_other_levels(tmp_path):
    """An interrupted run (checkpoints/run.json) with other levels is not resumed; `reings eval`
    does not reuse a finished run of other levels, nor one without them for a config with them."""
    from reings.config import RunConfig
    from reings.evaluate import _settings_differ
    from reings.outputs import check_out
    from reings.pipeline import run_settings

    a = RunConfig(depth_prior="none", cross_warp_blur=(2, 4))
    for other in (RunConfig(depth_prior="none", cross_warp_blur=(2,)), RunConfig(depth_prior="none")):
        out = tmp_path / f"out{len(other.cross_warp_blur)}"
        (out / "checkpoints").mkdir(parents=True)
        (out / "checkpoints" / "run.json").write_text(json.dumps(run_settings(a.resolved(), "llff")))
        check_out(str(out), run_settings(a.resolved(), "llff"), False)  # the same settings: resumed
        with pytest.raises(ValueError, match="other settings.*cross_warp_blur"):
            check_out(str(out), run_settings(other.resolved(), "llff"), False)
        (out / "metrics.json").write_text(json.dumps({"config": run_settings(a.resolved(), "llff")}))
        assert _settings_differ(str(out / "metrics.json"), a, "llff") == ""
        assert "cross_warp_blur" in _settings_differ(str(out / "metrics.json"), other, "llff")


def test_a_run_records_the_levels(device):
    import reings

    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, iterations=(2, 2, 2), device=device, with_lpips=False, eval_every=0, quiet=True,
              views=3, extent="frusta", depth_prior="none")
    r = reings.run(method="reings", cross_warp_blur=(2.0, 4.0), **kw)
    m = r.metrics
    assert m["cross_warp_blur"] == [2.0, 4.0] and m["config"]["cross_warp_blur"] == [2.0, 4.0]
    fits = [s for s in m["stages"] if "config" in s]
    assert fits and all(list(s["config"]["loss"]["cross_warp_blur"]) == [2.0, 4.0] for s in fits)
    m = reings.run(method="reings", **kw).metrics
    assert "cross_warp_blur" not in m and "cross_warp_blur" not in m["config"]
# }}}
