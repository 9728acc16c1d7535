"""The view_warp term and the opacity decay inside the training loop (`reings.train.fit`,
`_Iteration.photometric_pass`; docs/binocular.md §4): the Trainer contract's kept frame
(`forward(keep=True)`), `view_warp`, `hold`, `backward(into=)` and `opacity_decay` on both engines.

Checked against independent references:
  - the composed gradient (training render's depth cotangent + the virtual render's colour
    cotangent, summed by `backward(into=)`) against a central difference of the float64 loss
    view_warp_fwd(render64(virtual).rgb, render64(train).depth) along random directions, on the
    reference backend; the difference's two ends share every discrete decision of the warp;
  - the opacity decay kernel against the float64 twin and against logit(f * sigmoid(x)) computed
    directly (moderate logits) and on poisoned logits;
  - `backward(into=)` against the sum of the two separate backwards;
  - a short fit with both on: the device engine against the host engine (bit-identical on PoCL,
    as tests/test_device_fit.py), and a resumed fit against the uninterrupted one;
  - the kept virtual frame against the schedule it replaced, which rendered the virtual view
    again just before its backward: the same bits (with DropGaussian and the shared soft depth
    term too), one forward fewer per iteration;
  - the fit with the sync-free binning (docs/perf_notes.md §8: the kept frame's counts in its own
    slot's ctrl) against the sync binning, with DropGaussian and the shared soft depth term: the
    same bits.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import assert_resumes_bit_identically, assert_same_state, binning, dngaussian_fit_case, fit_case
from reings.backends import get_backend
from reings.backends.opencl import quirks
from reings.backends.reference import render64
from reings.backends.reference_state import grad_add, opacity_decay_
from reings.backends.reference_view_warp import (opacity_decay, view_warp_fwd, view_warp_pattern,
                                                 virtual_camera)
from reings.state import TrainState
from reings.train import fit, warp_baseline
from reings.types import Gaussians

ATOL, RTOL = 2e-5, 1e-5


@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=12, view_warp_baseline=0.3),
                  densify=replace(cfg.densify, opacity_decay=0.99, opacity_decay_from=5))
    return scene, init, cfg


def _fit(case, device, **kw):
    return fit_case(case, device, **kw)


def _same_state(a, b, exact: bool, what: str):
    assert_same_state(a, b, exact, what, RTOL, ATOL)


# {{{ the composed gradient against a central difference (reference backend, float64)

def _tiny_scene():
    """Eight opaque-ish Gaussians in front of a textured card, a 40x32 camera."""
    import reings

    scene = reings.make_procedural_scene(n_views=2, width=40, height=32, supersample=1)
    cam = scene.cameras[0]
    rng = np.random.default_rng(3)
    c = cam.center
    fwd = cam.viewmat[2, :3]
    right, up = cam.viewmat[0, :3], cam.viewmat[1, :3]
    pts = c + fwd * rng.uniform(3.0, 4.0, (24, 1)) + right * rng.uniform(-1, 1, (24, 1)) + up * rng.uniform(-0.8, 0.8, (24, 1))
    g = Gaussians(pts.astype(np.float32), np.tile(np.array([1, 0, 0, 0], np.float32), (24, 1)),
                  np.full((24, 3), np.log(0.25), np.float32), rng.uniform(0.5, 2.0, 24).astype(np.float32),
                  (rng.normal(0, 0.6, (24, 1, 3))).astype(np.float32))
    gt = scene.images[0]
    return g, cam, gt


def _warp_loss64(g64: Gaussians, cam, vcam, gt, b):
    """The float64 loss of the composition (independent of the trainer code; the Gaussians are
    float32, the renders and the term float64)."""
    _, _, tr, _ = render64(g64, cam, (0, 0, 0), 0.01, None, False)
    _, _, vr, _ = render64(g64, vcam, (0, 0, 0), 0.01, None, False)
    return view_warp_fwd(vr.rgb, tr.depth, gt, cam.fx, b, 1.0, 0.05)[0], vr.rgb, tr.depth


def test_composed_gradient_matches_central_difference():
    g, cam, gt = _tiny_scene()
    b = 0.35
    vcam = virtual_camera(cam, b)
    be = get_backend("reference")
    tr = be.trainer([gt], engine="host")
    st = TrainState.from_gaussians(g, 0)
    tr.upload(st)
    virt = tr.forward(vcam, 1, (0, 0, 0), 0.01, keep=True)
    fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
    v_virt, v_depth = tr.view_warp(virt, fr, 0, b, 1.0, 0.05)
    assert tr.read_view_warp()["valid_fraction"] > 0.2
    gr = tr.hold(tr.backward(fr, None, v_depth))
    gr = tr.backward(virt, v_virt, into=gr)
    rng = np.random.default_rng(0)
    base = {k: np.asarray(getattr(g, f), np.float64) for k, f in
            (("means", "means"), ("log_scales", "log_scales"), ("opacity_logits", "opacity_logits"))}
    checked = 0
    for trial in range(30):
        name = ("means", "log_scales", "opacity_logits")[trial % 3]
        d = rng.normal(size=base[name].shape)
        d /= np.linalg.norm(d)
        eps = 2e-5
        ends, ps = [], []
        for s in (+1, -1):
            p = dict(base)
            p[name] = base[name] + s * eps * d
            g64 = Gaussians(p["means"], g.quats, p["log_scales"], p["opacity_logits"], g.sh)
            ps.append(np.asarray(getattr(g64, name), np.float64))  # Gaussians hold float32: the real step
            loss, vrgb, dep = _warp_loss64(g64, cam, vcam, gt, b)
            ends.append((loss, view_warp_pattern(vrgb, dep, gt, cam.fx, b)))
        if not np.array_equal(ends[0][1], ends[1][1]):
            continue  # a discrete decision flipped inside the step: the difference measures nothing
        fd = ends[0][0] - ends[1][0]
        an = float(np.sum(np.asarray(gr[name], np.float64) * (ps[0] - ps[1])))
        assert abs(fd - an) <= 2e-3 * max(abs(fd), abs(an)) + 1e-9, (name, fd, an)
        checked += abs(an) > 1e-7
    assert checked >= 10, f"only {checked} informative directions"
# }}}


# {{{ the pieces on both engines

def test_backward_into_is_the_sum(device, case):
    scene, init, cfg = case
    for engine in ("host", "device"):
        be = get_backend(device)
        tr = be.trainer(scene.images, engine=engine)
        st = TrainState.from_gaussians(init, 1)
        tr.upload(st)
        parts = []
        for cam in scene.cameras[:2]:
            fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
            v = tr.photometric(fr, 0, 0.8, 0.2)
            g = tr.hold(tr.backward(fr, v))
            parts.append({k: _read(tr, g, k) for k in ("means", "opacity_logits", "sh_dc")})
        fr = tr.forward(scene.cameras[0], 1, (0, 0, 0), 0.01)
        held = tr.hold(tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2)))
        fr = tr.forward(scene.cameras[1], 1, (0, 0, 0), 0.01)
        both = tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2), into=held)
        for k in parts[0]:
            want = parts[0][k].copy()
            grad_add(want, parts[1][k])
            np.testing.assert_array_equal(_read(tr, both, k), want, err_msg=f"{engine} {k}")
            assert np.abs(parts[1][k]).max() > 0


def test_backward_hold_is_hold_of_the_backward(device, case):
    """backward(hold=True) gives hold(backward()) bit for bit, survives the next backward, and a later
    opacity-only backward into it adds that field alone (project_bwd's accumulate mode on the device)."""
    scene, init, cfg = case
    for engine in ("host", "device"):
        be = get_backend(device)
        tr = be.trainer(scene.images, engine=engine)
        tr.upload(TrainState.from_gaussians(init, 1))
        fr = tr.forward(scene.cameras[0], 1, (0, 0, 0), 0.01)
        want = tr.hold(tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2)))
        want = {k: _read(tr, want, k) for k in ("means", "quats", "log_scales", "opacity_logits", "sh_dc")}
        fr2 = tr.forward(scene.cameras[1], 1, (0, 0, 0), 0.01)
        alone = _read(tr, tr.backward(fr2, tr.photometric(fr2, 1, 0.8, 0.2), grad_fields=("opacity_logits",)),
                      "opacity_logits")
        fr = tr.forward(scene.cameras[0], 1, (0, 0, 0), 0.01)
        held = tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2), hold=True)
        for k, w in want.items():
            np.testing.assert_array_equal(_read(tr, held, k), w, err_msg=f"{engine} {k}")
        fr2 = tr.forward(scene.cameras[1], 1, (0, 0, 0), 0.01)
        both = tr.backward(fr2, tr.photometric(fr2, 1, 0.8, 0.2), grad_fields=("opacity_logits",), into=held)
        for k, w in want.items():
            if k == "opacity_logits":
                w = w.copy()
                grad_add(w, alone)
                assert np.abs(alone).max() > 0
            np.testing.assert_array_equal(_read(tr, both, k), w, err_msg=f"{engine} {k} after into")
        assert tr.hold(held) is not None  # holding held gradients again: nothing to copy (no overlap error)


@pytest.mark.parametrize("k", [1, 4])
def test_backward_into_adds_every_field(device, case, k):
    """backward(hold=True) then a full backward into it: every field (means, quats, log_scales, opacities and
    both SH groups at k coefficients) is the float32 sum of the two backwards, on both engines (the device
    engine's project_bwd accumulate mode, every field)."""
    scene, init, cfg = case
    rng = np.random.default_rng(5)  # anisotropic scales and SH colours: every field has a gradient
    init = replace(init, log_scales=(init.log_scales + rng.normal(0, 0.4, init.log_scales.shape)).astype(np.float32),
                   sh=(init.sh + rng.normal(0, 0.2, init.sh.shape)).astype(np.float32))
    fields = ("means", "quats", "log_scales", "opacity_logits", "sh_dc") + (("sh_rest",) if k > 1 else ())
    for engine in ("host", "device"):
        be = get_backend(device)
        tr = be.trainer(scene.images, engine=engine)
        tr.upload(TrainState.from_gaussians(init, 1))
        parts = []
        for i in (0, 1):
            fr = tr.forward(scene.cameras[i], k, (0, 0, 0), 0.01)
            g = tr.backward(fr, tr.photometric(fr, i, 0.8, 0.2))
            parts.append({f: _read(tr, g, f) for f in fields})
        fr = tr.forward(scene.cameras[0], k, (0, 0, 0), 0.01)
        held = tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2), hold=True)
        fr = tr.forward(scene.cameras[1], k, (0, 0, 0), 0.01)
        both = tr.backward(fr, tr.photometric(fr, 1, 0.8, 0.2), into=held)
        for f in fields:
            want = parts[0][f].copy()
            grad_add(want, parts[1][f])
            assert np.abs(parts[1][f]).max() > 0, f
            np.testing.assert_array_equal(_read(tr, both, f), want, err_msg=f"{engine} k={k} {f}")


def _read(tr, grads, name):
    """A gradient group of either trainer as a host float32 array."""
    if isinstance(grads[name if name in grads else "sh"], np.ndarray):
        return np.array(grads[name], np.float32)
    buf, stride, off, cols = tr._grad_view(grads, name)
    a = np.empty((tr.n, stride), np.float32)
    tr.cl.enqueue_copy(tr.queue, a, buf)
    return a[:, off:off + cols].copy()


POISON = np.array([0.0, -0.0, 1e-30, -1e-30, 1.0, -1.0, 5.0, -5.0, 20.0, -20.0, 88.0, -88.0, 90.0, -104.0,
                   1e30, -1e30, 3.4e38, -3.4e38, np.inf, -np.inf, np.nan], np.float32)


def test_opacity_decay_twin_is_logit_of_scaled_sigmoid():
    x = np.linspace(-30, 30, 601)
    for f in (0.5, 0.9, 0.995):
        s = f / (1 + np.exp(-x))
        np.testing.assert_allclose(opacity_decay(x, f), np.log(s / (1 - s)), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(opacity_decay(x, 1.0), x)
    for bad in (0.0, -0.1, 1.5, np.nan):
        with pytest.raises(ValueError):
            opacity_decay(x, bad)
    y = POISON.copy()
    opacity_decay_(y, 0.995)
    assert np.isnan(y[-1]) and y[-2] == -np.inf and np.isfinite(y[:-3]).all() and np.isfinite(y[-3])
    assert (np.diff(np.sort(y[np.isfinite(y)])) >= 0).all()


def test_opacity_decay_kernel_matches_twin(device):
    rng = np.random.default_rng(1)
    x = np.concatenate([POISON, rng.normal(0, 8, 4000).astype(np.float32)])
    g = Gaussians(np.zeros((len(x), 3), np.float32), np.tile(np.float32([1, 0, 0, 0]), (len(x), 1)),
                  np.zeros((len(x), 3), np.float32), x, np.zeros((len(x), 1, 3), np.float32))
    be = get_backend(device)
    tr = be.trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(TrainState.from_gaussians(g, 0))
    for f in (0.995, 0.5):
        tr.opacity_decay(f)
    got = tr.read_params(("opacity_logits",))["opacity_logits"]
    want = x.copy()
    opacity_decay_(want, 0.995)
    opacity_decay_(want, 0.5)
    fin = np.isfinite(want)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got[~fin & ~np.isnan(want)], want[~fin & ~np.isnan(want)])
    ulp = np.abs(got[fin].astype(np.float64) - want[fin]) / np.spacing(np.abs(want[fin]).astype(np.float32))
    limit = 0 if quirks.is_pocl(be.handle.device) and tr.fp64 else 4
    assert ulp.max() <= limit, ulp.max()
    host = be.trainer([np.zeros((4, 4, 3), np.float32)], engine="host")
    st = TrainState.from_gaussians(g, 0)
    host.upload(st)
    host.opacity_decay(0.995)
    w1 = x.copy()
    opacity_decay_(w1, 0.995)
    np.testing.assert_array_equal(st.params["opacity_logits"], w1)
# }}}


# {{{ a short fit with both terms on

def test_fit_device_matches_host(device, case):
    host = _fit(case, device, engine="host")
    dev = _fit(case, device, engine="device")
    assert [it for it, *_ in host.history.view_warp] == [15, 20, 23]
    assert [it for it, *_ in dev.history.view_warp] == [15, 20, 23]
    for (_, lh, vh), (_, ld, vd) in zip(host.history.view_warp, dev.history.view_warp):
        assert lh > 0 and 0 < vh <= 1
        np.testing.assert_allclose([ld, vd], [lh, vh], rtol=1e-5)
    np.testing.assert_allclose(dev.history.loss, host.history.loss, rtol=1e-5)
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _same_state(host.state, dev.state, exact, "device vs host engine with view_warp and opacity decay")


@pytest.mark.parametrize("every", [1, 3, 5])
def test_view_warp_every_takes_every_nth_iteration_at_n_times_the_weight(device, case, every, monkeypatch):
    """LossConfig.view_warp_every N: the term at iterations view_warp_from + k N only (12, 15, 18, 21 of
    the case's 23 at N = 3; 12, 17, 22 at N = 5, where `it % N` would pick others), each with weight N times
    view_warp_weight and the smoothness weight as given; the host engine's calls are spied, the device
    engine's final state agrees with the host engine's (bit for bit on PoCL)."""
    from reings.backends.host_trainer import HostTrainer

    scene, init, cfg = case
    sc = (scene, init, replace(cfg, loss=replace(cfg.loss, view_warp_weight=0.5, view_warp_every=every)))
    calls = []
    real = HostTrainer.view_warp

    def spy(self, virt, fr, view, baseline, weight, smooth_weight, scale=1):
        assert smooth_weight == cfg.loss.view_warp_smooth and scale == cfg.loss.view_warp_scale
        calls.append((self.state.iteration, weight))  # state.iteration: the iteration before this one
        return real(self, virt, fr, view, baseline, weight, smooth_weight, scale)

    monkeypatch.setattr(HostTrainer, "view_warp", spy)
    host = _fit(sc, device, engine="host")
    want_its = list(range(12, 24, every))
    assert [it + 1 for it, _ in calls] == want_its
    assert all(w == 0.5 * every for _, w in calls)
    assert [it for it, *_ in host.history.view_warp] == [it for it in (15, 20, 23) if it in want_its]
    dev = _fit(sc, device, engine="device")
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _same_state(host.state, dev.state, exact, f"device vs host engine, view_warp_every {every}")


@pytest.mark.parametrize("bad", [0, -2, 1.5, True])
def test_view_warp_every_refuses_what_is_not_a_count(case, bad):
    scene, init, cfg = case
    with pytest.raises(ValueError, match="view_warp_every"):
        fit_case((scene, init, replace(cfg, loss=replace(cfg.loss, view_warp_every=bad))), "reference")
    from reings.config import LossConfig, count_at_least_1

    assert count_at_least_1(bad) and count_at_least_1(np.int64(2)) is None  # the config's rule is fit's
    assert LossConfig(view_warp_every=np.int64(3)).view_warp_every == 3


def test_fit_device_matches_host_with_shared_soft_depth(device, case):
    """The soft depth term on the photometric render (soft_depth_shared) together with the
    view_warp term: both add into the held gradients; the engines agree (bit for bit on PoCL)."""
    scene, init, cfg = case
    sc = (scene, init, replace(cfg, loss=replace(cfg.loss, soft_depth_shared=True)))
    host = _fit(sc, device, engine="host")
    dev = _fit(sc, device, engine="device")
    assert [it for it, *_ in dev.history.view_warp] == [15, 20, 23]
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _same_state(host.state, dev.state, exact, "device vs host engine with view_warp and the shared soft depth")
    two = _fit(case, device, engine="device")
    assert not np.array_equal(two.state.params["opacity_logits"], dev.state.params["opacity_logits"])


def test_backward_into_adds_only_the_asked_fields(device, case):
    """backward(grad_fields=("opacity_logits",), into=held) adds the opacities' gradient and
    leaves every other held group as it was."""
    scene, init, cfg = case
    for engine in ("host", "device"):
        tr = get_backend(device).trainer(scene.images, engine=engine)
        tr.upload(TrainState.from_gaussians(init, 1))
        fr = tr.forward(scene.cameras[0], 1, (0, 0, 0), 0.01)
        held = tr.hold(tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2)))
        before = {k: _read(tr, held, k) for k in ("means", "opacity_logits", "sh_dc")}
        fr = tr.forward(scene.cameras[1], 1, (0, 0, 0), 0.01)
        v = tr.photometric(fr, 1, 0.8, 0.2)
        alone = {k: _read(tr, tr.backward(fr, v), k) for k in ("means", "opacity_logits", "sh_dc")}
        both = tr.backward(fr, v, None, None, ("opacity_logits",), into=held)
        want = before["opacity_logits"].copy()
        grad_add(want, alone["opacity_logits"])
        np.testing.assert_array_equal(_read(tr, both, "opacity_logits"), want, err_msg=engine)
        for k in ("means", "sh_dc"):
            assert np.abs(alone[k]).max() > 0
            np.testing.assert_array_equal(_read(tr, both, k), before[k], err_msg=f"{engine} {k}")


def test_fit_terms_change_the_result(device, case):
    """Each switch changes the fit (a wiring that dropped a term would leave the state as it is
    with the term off)."""
    scene, init, cfg = case
    on = _fit(case, device).state.params["means"]
    for off in (replace(cfg, loss=replace(cfg.loss, view_warp_weight=0.0)),
                replace(cfg, densify=replace(cfg.densify, opacity_decay=None))):
        r = fit(scene, off, device=device, init=init, depth_targets=list(scene.depths), progress=False)
        p = r.state.params["means"]
        assert p.shape != on.shape or np.abs(p - on).max() > 1e-4


def test_fit_resume_is_bit_identical(device, case, tmp_path):
    """Stopped at 17, last checkpoint at 15: inside the view_warp span."""
    ref, res = assert_resumes_bit_identically(case, device, tmp_path, stop_at=17)
    assert [tuple(x) for x in res.history.view_warp] == [tuple(x) for x in ref.history.view_warp]


def test_kept_frame_survives_ordinary_forwards_and_backwards(device, case):
    """The virtual view as a kept frame (`forward(keep=True)`), read and backpropagated after the
    training view's forward and backward: its image and gradients are those of the same render
    done again just before its backward (the schedule before the kept frame), bit for bit."""
    scene, init, cfg = case
    cam, vcam = scene.cameras[0], virtual_camera(scene.cameras[0], 0.3)
    for engine in ("host", "device"):
        got, want = [], []
        for again in (False, True):
            tr = get_backend(device).trainer(scene.images, engine=engine)
            tr.upload(TrainState.from_gaussians(init, 1))
            virt = tr.forward(vcam, 1, (0, 0, 0), 0.01, keep=True)
            rgb = tr.read_rgb(virt).copy()
            fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
            v_virt, v_depth = tr.view_warp(virt, fr, 0, 0.3, 1.0, 0.05)
            held = tr.hold(tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2), v_depth))
            tr.accumulate(fr)
            if again:
                virt = tr.forward(vcam, 1, (0, 0, 0), 0.01)
            out = want if again else got
            out.append(tr.read_rgb(virt).copy())
            np.testing.assert_array_equal(out[-1], rgb, err_msg=engine)
            both = tr.backward(virt, v_virt, into=held)
            out.extend(_read(tr, both, k) for k in ("means", "quats", "log_scales", "opacity_logits", "sh_dc"))
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b, err_msg=engine)
        assert np.abs(got[1]).max() > 0


def test_fit_with_the_kept_frame_matches_rendering_it_again(device, case, monkeypatch):
    """The fit with the virtual view rendered once (a kept frame) against the schedule it replaced,
    where the virtual view was rendered again, into the ordinary frame slot, just before its
    backward: the same bits, with DropGaussian and the shared soft depth term too."""
    from reings.backends.opencl.trainer import DeviceTrainer

    scene, init, cfg = case
    variants = (case, (scene, init, replace(cfg, loss=replace(cfg.loss, drop_gamma=0.2, soft_depth_shared=True))))
    kept = [_fit(c, device, engine="device") for c in variants]
    forward, backward = DeviceTrainer.forward, DeviceTrainer.backward
    redone = []

    def noting_forward(self, *a, keep=False, **kw):
        fr = forward(self, *a, keep=keep, **kw)
        if keep:
            self.redo = (fr, a, kw)
        return fr

    def backward_of_a_fresh_render(self, fr, *a, **kw):
        if getattr(self, "redo", (None,))[0] is fr:
            _, fa, fkw = self.redo
            fr = forward(self, *fa, **fkw)
            redone.append(fr)
        return backward(self, fr, *a, **kw)

    monkeypatch.setattr(DeviceTrainer, "forward", noting_forward)
    monkeypatch.setattr(DeviceTrainer, "backward", backward_of_a_fresh_render)
    again = [_fit(c, device, engine="device") for c in variants]
    assert len(redone) == 2 * (cfg.iterations - cfg.loss.view_warp_from + 1)
    for k, a, what in zip(kept, again, ("view_warp", "view_warp, drop, shared soft depth")):
        _same_state(k.state, a.state, True, f"kept frame vs rendered again ({what})")
        assert k.history.loss == a.history.loss and k.history.view_warp == a.history.view_warp


def test_fit_sync_free_binning_is_bit_identical(device, case):
    """Kept frames (slot 1), DropGaussian and the shared soft depth term, binned sync-free against
    in sync: the same state and histories."""
    scene, init, cfg = case
    c = (scene, init, replace(cfg, loss=replace(cfg.loss, drop_gamma=0.2, soft_depth_shared=True)))
    be = get_backend(device)
    runs = {}
    for mode in ("sync", "async"):
        with binning(be, mode) as done:
            runs[mode] = _fit(c, device, engine="device")
        assert done[mode] > cfg.iterations and sum(done.values()) == done[mode], done
    a, b = runs["sync"], runs["async"]
    _same_state(a.state, b.state, True, "sync-free vs sync binning (view_warp, drop, shared soft depth)")
    assert a.history.loss == b.history.loss and a.history.view_warp == b.history.view_warp


def test_baselines_are_per_iteration_and_bounded():
    bs = [warp_baseline(0, it, 0.4) for it in range(1, 400)]
    assert all(-0.4 <= b <= 0.4 for b in bs) and min(bs) < -0.2 and max(bs) > 0.2
    assert bs == [warp_baseline(0, it, 0.4) for it in range(1, 400)]
    assert bs != [warp_baseline(1, it, 0.4) for it in range(1, 400)]
# }}}
