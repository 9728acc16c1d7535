"""The metric depth term (kernels/depth_metric.cl; reference_loss.depth_metric_fwd_bwd; the
depth_metric call of train._Iteration.photometric_pass; docs/method.md §10) against independent
references: a hand-computed case, central differences of the float64 twin and of the loss through
the float64 render, the kernel against the twin (with invalid pixels: zero weight, zero / NaN /
infinite targets, NaN depths), the host trainer's float32 mirror against the kernel bit for bit,
the device engine against the host engine on a short fit, and Oclgrind."""
from __future__ import annotations

import types
from dataclasses import replace

import numpy as np
import pytest

from cases import assert_engines_agree, assert_fd_along_random_directions, dngaussian_fit_case, gaussians_before
from reings.backends import get_backend
from reings.backends.reference import render64
from reings.backends.reference_loss import depth_metric_fwd_bwd, depth_metric_scale, depth_metric_valid
from reings.state import TrainState
from reings.train import fit


def test_twin_hand_case():
    d = np.array([[2.0, 1.0], [3.0, 5.0]])
    a = np.array([[1.0, 0.5], [1.0, 1.0]])
    t = np.array([[1.0, 4.0], [0.0, 5.0]])  # pixel (1, 0): no target; (1, 1): a tie
    c = np.array([[1.0, 0.5], [1.0, 0.25]])
    loss, g = depth_metric_fwd_bwd(d, a, t, c, 2.0)
    # valid: (0,0), (0,1), (1,1); S = 1 + 0.5 + 0.25 = 1.75; scale = 2 / 1.75
    s = 2.0 / 1.75
    assert loss == pytest.approx(s * (1.0 * abs(2 - 1) / 1 + 0.5 * abs(1 - 2) / 4 + 0.25 * 0 / 5))
    np.testing.assert_allclose(g, [[s * 1.0, -s * 0.5 / 4], [0.0, 0.0]], rtol=0, atol=1e-15)
    assert depth_metric_scale(t, c, 2.0) == pytest.approx(s)
    assert depth_metric_scale(t, np.zeros_like(c), 2.0) == 0.0
    assert depth_metric_fwd_bwd(d, a, t, np.zeros_like(c), 2.0)[0] == 0.0
    with pytest.raises(ValueError):
        depth_metric_fwd_bwd(d, a, t[:1], c, 1.0)


def test_twin_gradient_fd():
    rng = np.random.default_rng(3)
    h, w = 9, 11
    t = rng.uniform(1, 5, (h, w))
    a = rng.uniform(0.2, 1, (h, w))
    d = a * t * rng.uniform(0.5, 1.5, (h, w))
    d[np.abs(d - a * t) < 1e-3] += 0.01  # away from the kinks
    c = rng.uniform(0, 1, (h, w)) * (rng.uniform(size=(h, w)) > 0.2)
    t[0, :3] = [0.0, np.nan, np.inf]
    loss, g = depth_metric_fwd_bwd(d, a, t, c, 0.7)
    for trial in range(5):
        v = rng.normal(size=(h, w))
        e = 1e-6
        fd = (depth_metric_fwd_bwd(d + e * v, a, t, c, 0.7)[0] - depth_metric_fwd_bwd(d - e * v, a, t, c, 0.7)[0]) / (2 * e)
        assert fd == pytest.approx(float(np.sum(g * v)), rel=1e-7, abs=1e-12)
    assert np.all(g[0, :3] == 0) and loss > 0


def _maps(rng, h, w):
    t = rng.uniform(0.5, 6, (h, w)).astype(np.float32)
    a = rng.uniform(0, 1, (h, w)).astype(np.float32)
    d = (a * t * rng.uniform(0.3, 1.7, (h, w))).astype(np.float32)
    c = (rng.uniform(0, 1, (h, w)) * (rng.uniform(size=(h, w)) > 0.3)).astype(np.float32)
    t[0, :4] = [0.0, np.nan, np.inf, -1.0]
    d[1, :2] = [np.nan, np.inf]
    d[2, 0] = a[2, 0] * t[2, 0]  # a tie in float32
    return d, a, t, c


def _frame(tr, d, a):
    import pyopencl as cl

    mf = cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR
    ctx = tr.handle.context
    h, w = d.shape
    return types.SimpleNamespace(width=w, height=h, bufs={"out_depth": cl.Buffer(ctx, mf, hostbuf=d),
                                                          "out_alpha": cl.Buffer(ctx, mf, hostbuf=a)})


def test_kernel_matches_twin_and_host_mirror(device):
    rng = np.random.default_rng(5)
    h, w = 37, 53
    d, a, t, c = _maps(rng, h, w)
    dev = get_backend(device).trainer([np.zeros((h, w, 3), np.float32)], engine="device")
    host = get_backend(device).trainer([np.zeros((h, w, 3), np.float32)], engine="host")
    for tr in (dev, host):
        tr.upload_depth_targets([t], [(h, w)])
        tr.upload_depth_metric([c])
    fr = _frame(dev, d, a)
    hfr = types.SimpleNamespace(width=w, height=h, out=types.SimpleNamespace(depth=d, alpha=a))
    got = dev._read(dev.depth_metric(fr, 0, 0.3), (h, w), np.float32)
    mirror = host.depth_metric(hfr, 0, 0.3)
    loss64, g64 = depth_metric_fwd_bwd(d, a, t, c, 0.3)
    ok = depth_metric_valid(t, c) & np.isfinite(d)
    np.testing.assert_allclose(got[ok], g64[ok], rtol=2e-6, atol=0)
    assert np.all(got[~depth_metric_valid(t, c)] == 0) and got[1, 0] == 0 and got[2, 0] == 0
    from reings.backends.opencl import quirks

    exact = quirks.is_pocl(get_backend(device).handle.device)  # NVIDIA's float division is not IEEE's
    cmp = np.testing.assert_array_equal if exact else (lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-6))
    cmp(got, mirror)  # the host trainer's float32 mirror, bit for bit on PoCL
    ld = dev.read_depth_metric()
    assert np.isfinite(ld) and ld == pytest.approx(host.read_depth_metric(), rel=1e-6)
    fin = np.isfinite(d)
    assert ld == pytest.approx(depth_metric_fwd_bwd(np.where(fin, d, a * t), a, t, c, 0.3)[0], rel=1e-5)
    # accumulate into another cotangent (the view_warp term's buffer on the device)
    base = rng.normal(size=(h, w)).astype(np.float32)
    import pyopencl as cl

    bb = cl.Buffer(dev.handle.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=base)
    acc = dev._read(dev.depth_metric(fr, 0, 0.3, into=bb), (h, w), np.float32)
    np.testing.assert_array_equal(acc, base + got)
    cmp(host.depth_metric(hfr, 0, 0.3, into=base.copy()), base + mirror)
    # a view without weights, or weight 0: no term (zeros)
    assert not np.any(dev._read(dev.depth_metric(fr, 0, 0.0), (h, w), np.float32))


def test_gradient_through_the_render_fd():
    """dL/d means and dL/d opacity logits of the term through the float64 render (host trainer on
    the reference backend) against central differences of the twin's loss."""
    import reings

    scene = reings.make_procedural_scene(n_views=2, width=24, height=20, supersample=1)
    cam = scene.cameras[0]
    rng = np.random.default_rng(2)
    g = gaussians_before(cam, rng, 14, opacity=(0, 2))
    target = np.full((20, 24), 3.2)
    conf = rng.uniform(0.2, 1, (20, 24))
    tr = get_backend("reference").trainer([scene.images[0]], engine="host")
    tr.upload(TrainState.from_gaussians(g, 0))
    tr.upload_depth_targets([target], [(20, 24)])
    tr.upload_depth_metric([conf])
    fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
    vd = tr.depth_metric(fr, 0, 1.0)
    gr = tr.backward(fr, None, vd, None, ("means", "opacity_logits"))
    alpha0 = fr.out.alpha  # the term holds alpha constant: so does the difference below

    def loss(gg):
        out = render64(gg, cam)[2]
        return depth_metric_fwd_bwd(out.depth, alpha0, target, conf, 1.0)[0]

    assert_fd_along_random_directions(loss, g, gr, (("means", 2e-2), ("opacity_logits", 2e-2)), rng)


def test_fit_with_depth_metric_device_matches_host(device):
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=21,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, depth_metric=0.5))
    conf = [np.where(np.arange(64)[None, :] < 40, 1.0, 0.0) * np.ones((48, 1)) for _ in scene.depths]
    kw = dict(device=device, init=init, depth_targets=list(scene.depths), depth_confidence=conf, progress=False,
              log_every=5)
    host = fit(scene, cfg, engine="host", **kw)
    dev = fit(scene, cfg, engine="device", **kw)
    from reings.backends.opencl import quirks

    if quirks.is_pocl(get_backend(device).handle.device):
        assert_engines_agree(device, host.state, dev.state, "depth_metric")
    else:  # the L1's sign flips where NVIDIA's division rounds D - a t the other way: a looser bound
        for k in host.state.params:
            np.testing.assert_allclose(dev.state.params[k], host.state.params[k], rtol=1e-4, atol=1e-4, err_msg=k)
    assert host.history.depth_metric and all(np.isfinite(v) and v >= 0 for _, v in host.history.depth_metric)
    off = fit(scene, replace(cfg, loss=replace(cfg.loss, depth_metric=0.0)), engine="device", **kw)
    assert not np.array_equal(off.state.params["means"], dev.state.params["means"])
    assert not off.history.depth_metric


_OCLGRIND_SCRIPT = """
import types
import numpy as np
import pyopencl as cl
from reings.backends import get_backend
h, w = 5, 7
rng = np.random.default_rng(0)
t = rng.uniform(1, 3, (h, w)).astype(np.float32); t[0, :3] = [0, np.nan, np.inf]
a = rng.uniform(0, 1, (h, w)).astype(np.float32)
d = (a * t * 1.2).astype(np.float32); d[1, 0] = np.nan
c = rng.uniform(0, 1, (h, w)).astype(np.float32); c[2, :2] = 0
tr = get_backend("oclgrind").trainer([np.zeros((h, w, 3), np.float32)], engine="device")
tr.upload_depth_targets([t], [(h, w)])
tr.upload_depth_metric([c])
mf = cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR
fr = types.SimpleNamespace(width=w, height=h, bufs={"out_depth": cl.Buffer(tr.handle.context, mf, hostbuf=d),
                                                  "out_alpha": cl.Buffer(tr.handle.context, mf, hostbuf=a)})
v = tr._read(tr.depth_metric(fr, 0, 0.5), (h, w), np.float32)
assert np.all(np.isfinite(v)) and v[0, 0] == 0 and v[1, 0] == 0 and v[2, 0] == 0
assert np.isfinite(tr.read_depth_metric())
print("ok")
"""


@pytest.mark.oclgrind
def test_oclgrind_checks():
    """depth_metric_grad and depth_metric_rows, with invalid pixels, under Oclgrind's checks."""
    from oclgrind_util import check_script

    check_script(_OCLGRIND_SCRIPT)


def test_options_and_priors():
    from reings.config import RunConfig
    from reings.pipeline import depth_metric_of

    assert depth_metric_of(RunConfig(depth_metric=0.5), "dtu") == 0.5
    assert depth_metric_of(RunConfig(), "dtu") == depth_metric_of(RunConfig(), "llff") == 0.0
    assert depth_metric_of(RunConfig(method="dngaussian", depth_metric=0.5), "llff") == 0.0
    assert depth_metric_of(RunConfig(depth_metric=0.5, depth_prior="exact"), "llff") == 0.5
    assert depth_metric_of(RunConfig(depth_prior="none"), "llff") == 0.0
    with pytest.raises(ValueError, match="metric depth prior"):
        RunConfig(depth_metric=0.5, depth_prior="onnx:model.onnx")
    with pytest.raises(ValueError, match="depth_metric"):
        RunConfig(depth_metric=-1.0)
