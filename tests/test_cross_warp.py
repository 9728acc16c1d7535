"""The cross-view photometric term (kernels/cross_warp.cl; reference_cross_warp.cross_warp_fwd_bwd;
the cross_warp call of train._Iteration.photometric_pass; docs/method.md §12) against independent
references: a hand-computed translation case, identical cameras and a pure rotation (no depth
gradient at all), central differences of the float64 twin and of the loss through the float64
render, the kernel against the twin (zero-alpha pixels, NaN / infinite / negative depths, points
behind the partner camera, the far border), the host trainer's float32 mirror against the kernel
bit for bit, the device engine against the host engine on a short fit, resume, off = no call, the
options, and Oclgrind. The occlusion test (LossConfig.cross_warp_occlusion): a hand-built near strip
in front of a far plane (exactly which pixels the partner cannot see), the kernel against the twin
and the mirror on random partner depths, central differences with it on, tolerance 0 = the term
without it bit for bit (kernel and fit), the engines, resume and Oclgrind with it on; the nearest
pixel (not floor) and the far border by hand, the pass's DropGaussian mask on the partner's render,
both trainers' refusals; the default's resolution for `make run` and in `reings eval`'s checks."""
from __future__ import annotations

import functools
import types
from dataclasses import replace

import numpy as np
import pytest

from cases import (assert_engines_agree, device_depth_frame, assert_fd_along_random_directions, assert_resumes_bit_identically,
                   assert_same_state, dngaussian_fit_case, fit_case, gaussians_before, make_camera, rotation_viewmat)
from reings.backends import get_backend
from reings.backends.opencl import quirks
from reings.backends.reference import render64
from reings.backends.reference_cross_warp import CROSS_WARP_ALPHA_MIN, cross_warp_args, cross_warp_fwd_bwd
from reings.state import TrainState
from reings.train import cross_partner
from reings.types import Camera

NEAR = 0.01


def _moved(cam: Camera, angles=(0.0, 0.0, 0.0), centre_shift=(0.0, 0.0, 0.0)) -> Camera:
    """`cam` rotated by `angles` (rotation_viewmat's, about its own centre) and its centre moved by
    `centre_shift` (world units)."""
    r = rotation_viewmat(angles, (0, 0, 0))[:3, :3] @ cam.viewmat[:3, :3]
    c = cam.center + np.asarray(centre_shift, np.float64)
    v = np.eye(4)
    v[:3, :3], v[:3, 3] = r, -r @ c
    return Camera(cam.K.copy(), v, cam.width, cam.height)


def _scale(w, h, weight):
    return np.float32(weight / (3.0 * h * w))


def _run(device, d, a, ii, ij, ci, cj, weight, into=None, tol=0.0, partner=None):
    """The device trainer's cross_warp on these maps: (dL/dD, read_cross_warp()); tol > 0: the
    occlusion test against partner = (depth_j, alpha_j), held by hold_depth."""
    import pyopencl as cl

    tr = get_backend(device).trainer([ii, ij], engine="device")
    mf = cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR
    held = None if partner is None else tr.hold_depth(device_depth_frame(tr, cj, *partner))
    bb = None if into is None else cl.Buffer(tr.handle.context, mf, hostbuf=np.ascontiguousarray(into, np.float32))
    v = tr.cross_warp(device_depth_frame(tr, ci, d, a), 0, 1, cj, weight, NEAR, into=bb, occlusion=tol,
                      partner_depth=held)
    return tr._read(v, d.shape, np.float32), tr.read_cross_warp()


def _host(d, a, ii, ij, ci, cj, weight, into=None, tol=0.0, partner=None):
    """The host trainer's cross_warp (the float32 mirror) on these maps (tol, partner: _run's)."""
    tr = get_backend("reference").trainer([ii, ij], engine="host")

    def frame(cam, dd, aa):
        return types.SimpleNamespace(width=cam.width, height=cam.height, cam=cam,
                                     out=types.SimpleNamespace(depth=dd, alpha=aa))

    held = None if partner is None else tr.hold_depth(frame(cj, *partner))
    g = tr.cross_warp(frame(ci, d, a), 0, 1, cj, weight, NEAR, into=into, occlusion=tol, partner_depth=held)
    return g, tr.read_cross_warp()


def _exact(device) -> bool:
    return quirks.is_pocl(get_backend(device).handle.device)  # NVIDIA's float division is not IEEE's


# {{{ the float64 twin

def test_twin_hand_case_translation():
    """Camera j = camera i moved by b along its x axis, constant depth z, I_j a ramp in x, I_i = 0:
    p' = p - f b / z, r_c = k_c (x - f b / z), dL/dD = scale / a * sum_c k_c f b / z^2."""
    h, w, f, b, z = 6, 12, 10.0, 0.3, 2.0  # shift f b / z = 1.5 px
    ci = make_camera(w, h, f=f)
    cj = _moved(ci, centre_shift=(b, 0, 0))
    k = np.array([0.01, 0.02, 0.03])
    ij = np.broadcast_to(np.arange(w)[None, :, None] * k, (h, w, 3)).copy()
    ii = np.zeros((h, w, 3))
    a = np.full((h, w), 0.8)
    a[0, 0] = 0.4  # below alpha_min: out
    d = a * z
    loss, g, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 2.0, NEAR)
    xs = np.arange(w)
    want_ok = np.broadcast_to(xs - 1.5 >= 0, (h, w)).copy()
    want_ok[0, 0] = False
    np.testing.assert_array_equal(ok, want_ok)
    s = 2.0 / (3 * h * w)
    r = (xs - 1.5)[None, :, None] * k
    assert loss == pytest.approx(s * np.sum(np.where(want_ok[..., None], np.abs(r), 0)), rel=1e-12)
    want_g = np.where(want_ok, s / a * np.sum(k) * f * b / z ** 2, 0)
    np.testing.assert_allclose(g, want_g, rtol=1e-10, atol=1e-15)


def test_twin_identical_and_rotation_only_cameras():
    rng = np.random.default_rng(1)
    h, w = 9, 13
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    d = rng.uniform(1, 4, (h, w))
    a = np.ones((h, w))
    ii, ij = rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 1, (h, w, 3))
    loss, g, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, ci, 1.0, NEAR)
    # every pixel reprojects onto itself; those of the image's edge land on the border, in or out
    # by a float64 rounding (the kernel's exact arithmetic keeps them all: the kernel tests)
    assert ok[1:-1, 1:-1].all()
    assert loss == pytest.approx(np.sum(np.where(ok[..., None], np.abs(ij - ii), 0)) / (3 * h * w), rel=1e-9)
    assert np.abs(g).max() < 1e-12
    ro = _moved(ci, angles=(0.05, -0.04, 0.1))  # same centre: no translation
    _, g, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, ro, 1.0, NEAR)
    assert ok.any() and np.abs(g).max() < 1e-12


@pytest.mark.parametrize("tol", [0.0, 0.03])
def test_twin_gradient_fd(tol):
    """Central differences of the twin's loss along random directions of the depth: each pixel's
    term depends on its own depth only, smoothly away from the L1 kink and the bilinear cell edges
    (which a 1e-7 step crosses with negligible probability on these random maps). tol > 0: with the
    occlusion test against a random partner depth (a constant), which leaves out a good share of
    the pixels; the step moves no pixel across it (nor p' across a partner pixel) but with the
    same negligible probability."""
    rng = np.random.default_rng(3)
    h, w = 14, 18
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    cj = _moved(ci, angles=(0.02, 0.05, -0.03), centre_shift=(0.4, -0.1, 0.05))
    d0 = rng.uniform(1.5, 4, (h, w))
    a = rng.uniform(0.3, 1, (h, w))
    d = d0 * a
    ii, ij = rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 1, (h, w, 3))
    aj = rng.uniform(0.3, 1, (h, w))
    occ = dict(occlusion=tol, depth_j=aj * rng.uniform(1.0, 4.5, (h, w)), alpha_j=aj)
    loss, g, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 0.7, NEAR, **occ)
    assert ok.sum() > 0.2 * h * w and (~ok).sum() > 0 and np.abs(g[ok]).max() > 0
    if tol:
        occluded = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 0.7, NEAR)[2] & ~ok
        assert occluded.sum() > 0.1 * h * w and not np.any(g[occluded])
    e = 1e-7
    for trial in range(5):
        v = rng.normal(size=(h, w))
        fd = (cross_warp_fwd_bwd(d + e * v, a, ii, ij, ci, cj, 0.7, NEAR, **occ)[0]
              - cross_warp_fwd_bwd(d - e * v, a, ii, ij, ci, cj, 0.7, NEAR, **occ)[0]) / (2 * e)
        an = float(np.sum(g * v))
        assert fd == pytest.approx(an, rel=1e-5, abs=1e-10), trial


def _strip_case(tol):
    """A near strip (z = 2, X in [0.3, 1.1] in camera i's frame, every Y) in front of a far plane
    (z = 4), seen by camera i and by camera j, camera i moved by b = 0.5 along x (f = 16, c_x = 16,
    W = 32): the maps of both views (the partner's depth as a render gives it, D_j = a_j Z_j) and
    the pixels the occlusion test must leave out, worked out column by column from the geometry
    alone. Rows of the partner: 0, 5 as built; 1 alpha 0.3 (below alpha_min: no test); 2 alpha
    exactly alpha_min; 3 the far plane a little nearer, 4 / (1 + tol / 2) (inside the tolerance);
    4 the far plane at 4 / (1 + 2 tol) (beyond it: every far pixel of view i is hidden)."""
    h, w, f, b, x0, x1 = 6, 32, 16.0, 0.5, 0.3, 1.1
    ci = make_camera(w, h, f=f)
    cj = _moved(ci, centre_shift=(b, 0, 0))
    cols = np.arange(w) + 0.5 - ci.cx
    zi = np.where((2 * cols / f >= x0) & (2 * cols / f <= x1), 2.0, 4.0)  # view i: the strip hides the plane
    zj = np.where((2 * cols / f + b >= x0) & (2 * cols / f + b <= x1), 2.0, 4.0)  # view j's rays: X = X_j + b
    a = np.ones((h, w))
    d = a * zi
    aj = np.ones((h, w))
    aj[1], aj[2] = 0.3, CROSS_WARP_ALPHA_MIN
    zjr = np.tile(zj, (h, 1))
    zjr[3][zj == 4] = 4 / (1 + tol / 2)
    zjr[4][zj == 4] = 4 / (1 + 2 * tol)
    # view i's pixel x at depth z lands at p'_x = x - f b / z in view j (2 px at the plane, 4 on the strip)
    px = np.arange(w) - f * b / zi
    seen = (px >= 0) & (px <= w - 1)
    hidden = np.zeros((h, w), bool)
    for y in range(h):
        for x in np.flatnonzero(seen):
            xn = int(np.floor(px[x] + 0.5))
            if aj[y, xn] >= CROSS_WARP_ALPHA_MIN and zi[x] > zjr[y, xn] * (1 + tol):
                hidden[y, x] = True
    rng = np.random.default_rng(13)
    ii, ij = rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 1, (h, w, 3))
    maps = [m.astype(np.float32) for m in (d, a, ii, ij, aj * zjr, aj)]
    return ci, cj, maps, seen, hidden


def test_occlusion_strip_in_front_of_a_plane(device):
    """_strip_case: the far-plane pixels just left of the strip in view i (x = 16, 17) are behind
    the strip for camera j; the strip's own pixels, seen by both, are not hidden. Exactly those
    pixels are left out by the twin, the kernel and the mirror; the others keep the values they
    have without the test, bit for bit; and the occluded fraction counts them."""
    tol = 0.05
    ci, cj, (d, a, ii, ij, dj, aj), seen, hidden = _strip_case(tol)
    for y in (0, 2, 3, 5):
        assert list(np.flatnonzero(hidden[y])) == [16, 17]
    assert not hidden[1].any()  # the partner's alpha is below alpha_min: no test
    assert list(np.flatnonzero(hidden[4])) == [x for x in range(2, 32) if not 18 <= x <= 24]
    ok0 = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR)[2]
    np.testing.assert_array_equal(ok0, np.broadcast_to(seen, ok0.shape))
    _, g64, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR, occlusion=tol, depth_j=dj, alpha_j=aj)
    np.testing.assert_array_equal(ok0 & ~ok, hidden)
    g0, st0 = _run(device, d, a, ii, ij, ci, cj, 1.0)
    g, st = _run(device, d, a, ii, ij, ci, cj, 1.0, tol=tol, partner=(dj, aj))
    np.testing.assert_array_equal(g, np.where(hidden, 0, g0))
    assert np.all(g0[hidden] != 0)
    assert st["occluded_fraction"] == hidden.mean() and st0["occluded_fraction"] == 0
    assert st["valid_fraction"] == ok.mean() and st0["valid_fraction"] == ok0.mean()
    mirror, hst = _host(d, a, ii, ij, ci, cj, 1.0, tol=tol, partner=(dj, aj))
    assert hst["occluded_fraction"] == hidden.mean() and hst["valid_fraction"] == ok.mean()
    np.testing.assert_array_equal(mirror == 0, g == 0)
    np.testing.assert_allclose(g, g64, rtol=1e-4, atol=1e-6 * np.abs(g64).max())
    # the loss loses the hidden pixels' residuals: the twin's sum over the pixels left valid
    loss0 = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR)[0]
    loss = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR, occlusion=tol, depth_j=dj, alpha_j=aj)[0]
    assert loss < loss0
    assert st["loss"] == pytest.approx(loss, rel=1e-5) and st0["loss"] == pytest.approx(loss0, rel=1e-5)


def test_kernel_occlusion_matches_twin_and_mirror(device):
    """Random partner depths and alphas (some below alpha_min, some 0) on _hard_maps: the kernel
    against the float64 twin (the occluded set and the gradient, but for the odd pixel at a float32
    rounding of p' across a pixel or cell edge) and against the host mirror bit for bit (PoCL);
    tolerance 0 with the partner given is the term without it, bit for bit; so is a tolerance so
    large that no depth is beyond it (the partner read, the arithmetic of the rest unchanged)."""
    rng = np.random.default_rng(17)
    h, w = 37, 53
    d, a, ii, ij = _hard_maps(rng, h, w)
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    cj = _moved(ci, angles=(0.03, 0.08, -0.02), centre_shift=(0.6, -0.2, 0.1))
    aj = rng.uniform(0.2, 1.0, (h, w)).astype(np.float32)
    aj[::7] = 0.0
    dj = (aj * rng.uniform(0.5, 5.0, (h, w))).astype(np.float32)
    tol = 0.04
    got, st = _run(device, d, a, ii, ij, ci, cj, 0.3, tol=tol, partner=(dj, aj))
    mirror, hst = _host(d, a, ii, ij, ci, cj, 0.3, tol=tol, partner=(dj, aj))
    _, g64, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 0.3, NEAR, occlusion=tol, depth_j=dj, alpha_j=aj)
    _, _, ok0 = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 0.3, NEAR)
    occ64 = ok0 & ~ok
    assert 0.08 < occ64.mean() < 0.6 and ok.mean() > 0.1
    nz = got != 0
    assert not np.any(nz & ~ok0)
    assert np.mean(nz == (ok & (g64 != 0))) > 0.98
    assert np.isclose(got, g64, rtol=1e-3, atol=1e-4 * np.abs(g64).max()).mean() > 0.98
    assert st["occluded_fraction"] == pytest.approx(occ64.mean(), abs=0.02)
    assert st["valid_fraction"] == pytest.approx(ok.mean(), abs=0.02)
    cmp = np.testing.assert_array_equal if _exact(device) else (lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5))
    cmp(got, mirror)
    assert (st["valid_fraction"], st["occluded_fraction"]) == (hst["valid_fraction"], hst["occluded_fraction"])
    assert st["loss"] == pytest.approx(hst["loss"], rel=1e-6)
    base = rng.normal(size=(h, w)).astype(np.float32)
    acc, _ = _run(device, d, a, ii, ij, ci, cj, 0.3, into=base, tol=tol, partner=(dj, aj))
    np.testing.assert_array_equal(acc, base + got)
    off, st_off = _run(device, d, a, ii, ij, ci, cj, 0.3)
    for t in (0.0, 1e30):
        g, stt = _run(device, d, a, ii, ij, ci, cj, 0.3, tol=t, partner=(dj, aj))
        np.testing.assert_array_equal(g, off)
        assert stt == st_off and stt["occluded_fraction"] == 0
        np.testing.assert_array_equal(_host(d, a, ii, ij, ci, cj, 0.3, tol=t, partner=(dj, aj))[0],
                                      _host(d, a, ii, ij, ci, cj, 0.3)[0])


def test_occlusion_on_exact_depths_leaves_out_mismatches():
    """The procedural scene's exact depths (alpha 1) of two training views: the test leaves out a
    share of the pixels (its objects occlude one another and the background), and those pixels'
    colours disagree across the views several times more than the ones kept (measured 0.19-0.22
    against 0.04-0.05 mean |r| at 64 x 48): it removes true mismatches, not a random set."""
    import reings

    s = reings.make_procedural_scene(n_views=3, width=64, height=48, supersample=1)
    for i, j in ((0, 1), (1, 2)):
        ci, cj, d = s.cameras[i], s.cameras[j], s.depths[i]
        one = np.ones_like(d)
        ok0 = cross_warp_fwd_bwd(d, one, s.images[i], s.images[j], ci, cj, 1.0, NEAR)[2]
        ok = cross_warp_fwd_bwd(d, one, s.images[i], s.images[j], ci, cj, 1.0, NEAR, occlusion=0.05,
                                depth_j=s.depths[j], alpha_j=np.ones_like(s.depths[j]))[2]
        hidden = ok0 & ~ok
        assert 0.02 < hidden.mean() < 0.3

        def mean_residual(m):  # the twin's loss over the pixels of m alone (alpha 0 elsewhere), per pixel
            return cross_warp_fwd_bwd(d, m.astype(float), s.images[i], s.images[j], ci, cj, 1.0, NEAR)[0] * d.size / m.sum()

        assert mean_residual(hidden) > 3 * mean_residual(ok), (i, j)


def test_occlusion_needs_the_partner_depth():
    rng = np.random.default_rng(19)
    h, w = 6, 8
    d, a, ii, ij = _hard_maps(rng, h, w)
    ci = make_camera(w, h)
    cj = _moved(ci, centre_shift=(0.1, 0, 0))
    with pytest.raises(ValueError, match="partner_depth"):
        _host(d, a, ii, ij, ci, cj, 1.0, tol=0.1)
    with pytest.raises(ValueError, match="depth_j"):
        cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR, occlusion=0.1)
    tr = get_backend("reference").trainer([ii, ij], engine="host")
    fr = types.SimpleNamespace(width=w, height=h, cam=ci, out=types.SimpleNamespace(depth=d, alpha=a))
    small = types.SimpleNamespace(width=w - 1, height=h, cam=cj, out=types.SimpleNamespace(depth=d[:, 1:], alpha=a[:, 1:]))
    with pytest.raises(ValueError, match="partner camera"):
        tr.cross_warp(fr, 0, 1, cj, 1.0, NEAR, occlusion=0.1, partner_depth=tr.hold_depth(small))
    old = tr.hold_depth(fr)
    tr.hold_depth(fr)
    with pytest.raises(ValueError, match="stale"):
        tr.cross_warp(fr, 0, 1, cj, 1.0, NEAR, occlusion=0.1, partner_depth=old)


def test_device_occlusion_needs_the_partner_depth(device):
    """The device trainer refuses what the host trainer refuses: no held depth, one of another
    size, one a later hold_depth made stale."""
    rng = np.random.default_rng(23)
    h, w = 6, 8
    d, a, ii, ij = _hard_maps(rng, h, w)
    ci = make_camera(w, h)
    cj = _moved(ci, centre_shift=(0.1, 0, 0))
    tr = get_backend(device).trainer([ii, ij], engine="device")
    fr = device_depth_frame(tr, ci, d, a)
    with pytest.raises(ValueError, match="partner_depth"):
        tr.cross_warp(fr, 0, 1, cj, 1.0, NEAR, occlusion=0.1)
    small = device_depth_frame(tr, Camera(cj.K.copy(), cj.viewmat.copy(), w - 1, h), d[:, 1:], a[:, 1:])
    with pytest.raises(ValueError, match="partner camera"):
        tr.cross_warp(fr, 0, 1, cj, 1.0, NEAR, occlusion=0.1, partner_depth=tr.hold_depth(small))
    old = tr.hold_depth(device_depth_frame(tr, cj, d, a))
    tr.hold_depth(device_depth_frame(tr, cj, d, a))
    with pytest.raises(ValueError, match="stale"):
        tr.cross_warp(fr, 0, 1, cj, 1.0, NEAR, occlusion=0.1, partner_depth=old)


def _occlusion_agrees(device, d, a, ii, ij, ci, cj, tol, dj, aj, want):
    """The twin, the kernel and the host mirror leave out exactly the pixels `want` ([H,W] bool):
    the twin's mask; the trainers' cotangents, zero there and those without the test elsewhere;
    their losses, the twin's over the pixels left (the left-out residuals are random); their counts."""
    ok0 = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR)[2]
    loss, _, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR, occlusion=tol, depth_j=dj, alpha_j=aj)
    np.testing.assert_array_equal(ok0 & ~ok, want)
    for run in (functools.partial(_run, device), _host):
        g0 = run(d, a, ii, ij, ci, cj, 1.0)[0]
        g, st = run(d, a, ii, ij, ci, cj, 1.0, tol=tol, partner=(dj, aj))
        np.testing.assert_array_equal(g, np.where(want, 0, g0))
        assert st["occluded_fraction"] == want.mean() and st["valid_fraction"] == ok.mean()
        assert st["loss"] == pytest.approx(loss, rel=1e-5)


def test_occlusion_reads_the_nearest_pixel(device):
    """A plane at z = 4 seen from two cameras a (0.575, 0.3) translation apart (f = 16): view i's
    pixel (x, y) lands at p' = (x - 2.3, y - 1.2), whose nearest pixel is (x - 2, y - 1) (floor
    would give (x - 3, y - 2), the bilinear cell's corner). The partner's surface nearer at one
    pixel (7, 5) hides exactly view i's pixel (9, 6)."""
    h, w, tol = 12, 20, 0.05
    ci = make_camera(w, h, f=16.0)
    cj = _moved(ci, centre_shift=(0.575, 0.3, 0.0))
    d, a = np.full((h, w), 4.0, np.float32), np.ones((h, w), np.float32)
    rng = np.random.default_rng(29)
    ii, ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32), rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    dj, aj = np.full((h, w), 4.0, np.float32), np.ones((h, w), np.float32)
    dj[5, 7] = 4.0 / (1 + 2 * tol)
    want = np.zeros((h, w), bool)
    want[6, 9] = True
    _occlusion_agrees(device, d, a, ii, ij, ci, cj, tol, dj, aj, want)


def test_occlusion_at_the_far_border(device):
    """Identical cameras (f = 16, a plane at z = 4: p' = p exactly in float64 and float32, the far
    row and column on the border): the partner's surface nearer along its last row and column and
    at (0, 0) hides exactly those pixels (the nearest pixel of u = W - 1 is W - 1, not the last
    bilinear cell's W - 2), but for one of the last row where the partner's alpha is below
    alpha_min (no test)."""
    h, w, tol = 7, 9, 0.05
    ci = make_camera(w, h, f=16.0)
    rng = np.random.default_rng(31)
    d, a = np.full((h, w), 4.0, np.float32), np.ones((h, w), np.float32)
    ii, ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32), rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    aj = np.ones((h, w), np.float32)
    aj[h - 1, 3] = 0.25
    want = np.zeros((h, w), bool)
    want[h - 1], want[:, w - 1], want[0, 0] = True, True, True
    want[h - 1, 3] = False
    dj = np.where(want | (aj < 1), d / (1 + 2 * tol), d).astype(np.float32) * aj
    assert cross_warp_fwd_bwd(d, a, ii, ij, ci, ci, 1.0, NEAR)[2].all()  # every pixel valid without the test
    _occlusion_agrees(device, d, a, ii, ij, ci, ci, tol, dj, aj, want)
# }}}


# {{{ the kernel against the twin and the host mirror

def _hard_maps(rng, h, w):
    d0 = rng.uniform(1.0, 5.0, (h, w)).astype(np.float32)
    a = rng.uniform(0.2, 1.0, (h, w)).astype(np.float32)
    a[0, :3] = [0.0, CROSS_WARP_ALPHA_MIN, np.nextafter(np.float32(CROSS_WARP_ALPHA_MIN), np.float32(0))]
    d = (d0 * a).astype(np.float32)
    d[1, :4] = [np.nan, np.inf, -1.0, 0.0]  # not a depth / behind camera i
    ii = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    return d, a, ii, ij


def test_kernel_matches_twin_and_host_mirror(device):
    rng = np.random.default_rng(5)
    h, w = 37, 53
    d, a, ii, ij = _hard_maps(rng, h, w)
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    cj = _moved(ci, angles=(0.03, 0.08, -0.02), centre_shift=(0.6, -0.2, 0.1))
    got, st = _run(device, d, a, ii, ij, ci, cj, 0.3)
    mirror, hst = _host(d, a, ii, ij, ci, cj, 0.3)
    loss64, g64, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 0.3, NEAR)
    assert 0.2 < ok.mean() < 0.95
    assert not ok[0, 0] and not ok[0, 2] and not ok[1, :4].any()  # alpha 0 / below alpha_min, bad depths
    nz = got != 0
    assert not np.any(nz & ~ok)  # no cotangent outside the twin's valid set
    # the float32 kernel against the float64 twin: equal validity and gradient but for the odd
    # pixel whose float32 position rounds across a cell edge or the border
    assert np.mean(nz == (ok & (g64 != 0))) > 0.99
    close = np.isclose(got, g64, rtol=1e-3, atol=1e-4 * np.abs(g64).max())
    assert close.mean() > 0.99
    assert st["loss"] == pytest.approx(loss64, rel=1e-3)
    assert st["valid_fraction"] == pytest.approx(ok.mean(), abs=0.01)
    cmp = np.testing.assert_array_equal if _exact(device) else (lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5))
    cmp(got, mirror)  # the host trainer's float32 mirror, bit for bit on PoCL
    assert st["valid_fraction"] == hst["valid_fraction"]
    assert st["loss"] == pytest.approx(hst["loss"], rel=1e-6)
    base = rng.normal(size=(h, w)).astype(np.float32)
    acc, _ = _run(device, d, a, ii, ij, ci, cj, 0.3, into=base)
    np.testing.assert_array_equal(acc, base + got)
    cmp(_host(d, a, ii, ij, ci, cj, 0.3, into=base.copy())[0], base + mirror)


def test_alpha_min_is_inclusive(device):
    """A pixel of alpha exactly CROSS_WARP_ALPHA_MIN that reprojects inside the partner image is
    valid (the twin's mask) and gets a cotangent from the kernel; one of the next float32 below it
    (same depth z = D / a) is invalid and gets none."""
    rng = np.random.default_rng(11)
    h, w = 16, 20
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    cj = _moved(ci, centre_shift=(0.05, 0.02, 0.0))
    amin = np.float32(CROSS_WARP_ALPHA_MIN)
    below = np.nextafter(amin, np.float32(0), dtype=np.float32)
    a = np.ones((h, w), np.float32)
    a[8, 10], a[8, 11] = amin, below
    d = (np.float32(2) * a).astype(np.float32)  # z = 2 exactly everywhere
    ii, ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32), rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    _, _, ok = cross_warp_fwd_bwd(d, a, ii, ij, ci, cj, 1.0, NEAR)
    assert ok[8, 10] and not ok[8, 11] and ok[8, 12]  # [8, 12]: alpha 1, inside as well
    got, _ = _run(device, d, a, ii, ij, ci, cj, 1.0)
    assert got[8, 10] != 0 and got[8, 12] != 0
    assert got[8, 11] == 0
    mirror, _ = _host(d, a, ii, ij, ci, cj, 1.0)
    assert mirror[8, 10] != 0 and mirror[8, 11] == 0


def test_kernel_identical_cameras_and_border(device):
    """Identical cameras: every pixel valid (the far row and column lie exactly on the border),
    the residual is I_j(p) - I_i(p) exactly, and the depth gradient is exactly 0."""
    rng = np.random.default_rng(7)
    h, w = 11, 17
    ci = make_camera(w, h, viewmat=rotation_viewmat())
    d = rng.uniform(1, 4, (h, w)).astype(np.float32)
    a = np.ones((h, w), np.float32)
    ii, ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32), rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    hm, e = cross_warp_args(ci, ci)
    np.testing.assert_array_equal(e, 0)
    g, st = _run(device, d, a, ii, ij, ci, ci, 0.9)
    assert st["valid_fraction"] == 1.0 and not np.any(g)
    rows = np.zeros(h, np.float32)
    for x in range(w):
        for c in range(3):
            rows = rows + np.abs(ij[:, x, c] - ii[:, x, c])
    want = float(_scale(w, h, 0.9)) * float(np.sum(rows.astype(np.float64)))
    assert st["loss"] == want  # the residuals of I_j(p) - I_i(p) themselves, summed in the kernel's order
    assert _host(d, a, ii, ij, ci, ci, 0.9)[1]["loss"] == want
    # a pure rotation (both centres at the origin, so t = 0 exactly): p' moves, but not with the depth
    c0 = make_camera(w, h, viewmat=rotation_viewmat(t=(0, 0, 0)))
    ro = _moved(c0, angles=(0.04, -0.06, 0.1))
    np.testing.assert_array_equal(cross_warp_args(c0, ro)[1], 0)
    g, st = _run(device, d, a, ii, ij, c0, ro, 0.9)
    assert 0 < st["valid_fraction"] < 1 and not np.any(g)
    loss64, _, _ = cross_warp_fwd_bwd(d, a, ii, ij, c0, ro, 0.9, NEAR)
    assert st["loss"] == pytest.approx(loss64, rel=1e-3)


def test_kernel_behind_the_partner_and_degenerate_partner(device):
    rng = np.random.default_rng(9)
    h, w = 8, 10
    ci = make_camera(w, h)
    d = rng.uniform(1, 3, (h, w)).astype(np.float32)
    a = np.ones((h, w), np.float32)
    ii, ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32), rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    back = _moved(ci, angles=(0.0, np.pi, 0.0))  # looks the other way from the same centre
    g, st = _run(device, d, a, ii, ij, ci, back, 1.0)
    assert st == {"loss": 0.0, "valid_fraction": 0.0, "occluded_fraction": 0.0} and not np.any(g)
    assert not cross_warp_fwd_bwd(d, a, ii, ij, ci, back, 1.0, NEAR)[2].any()
    ahead = _moved(ci, centre_shift=(0, 0, 5.0))  # in front of every point: behind it, z_j < 0
    g, st = _run(device, d, a, ii, ij, ci, ahead, 1.0)
    assert st["valid_fraction"] == 0.0 and not np.any(g)
    # a one-column partner image has no bilinear cell: nothing is valid
    one = Camera(ci.K.copy(), ci.viewmat.copy(), 1, h)
    g1, st1 = _host(d, a, ii, ij[:, :1].copy(), ci, one, 1.0)
    assert st1["valid_fraction"] == 0.0 and not np.any(g1)
# }}}


def test_gradient_through_the_render_fd():
    """dL/d opacity logits and dL/d means of the term through the float64 render (host trainer on
    the reference backend) against central differences of the twin's loss (alpha held). The
    means' differences are noisy (the Gaussians are float32, and the loss is piecewise linear in the
    sample position: bilinear cells, the L1), so they get a loose bound; the logits a tight one."""
    import reings

    scene = reings.make_procedural_scene(n_views=2, width=24, height=20, supersample=1)
    cam, cam2 = scene.cameras
    rng = np.random.default_rng(2)
    g = gaussians_before(cam, rng, 14, opacity=(1, 3))
    tr = get_backend("reference").trainer(list(scene.images), engine="host")
    tr.upload(TrainState.from_gaussians(g, 0))
    fr = tr.forward(cam, 1, (0, 0, 0), NEAR)
    vd = tr.cross_warp(fr, 0, 1, cam2, 1.0, NEAR)
    assert tr.read_cross_warp()["valid_fraction"] > 0.2 and np.abs(vd).max() > 0
    gr = tr.backward(fr, None, vd, None, ("means", "opacity_logits"))
    alpha0 = np.asarray(fr.out.alpha, np.float64)

    def loss(gg):
        out = render64(gg, cam)[2]
        return cross_warp_fwd_bwd(out.depth, alpha0, scene.images[0], scene.images[1], cam, cam2, 1.0, NEAR)[0]

    assert_fd_along_random_directions(loss, g, gr, (("opacity_logits", 2e-2), ("means", 0.3)), rng)


# {{{ in the fit

@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=21,
                                           soft_depth_from=3, densify_until=25)
    return scene, init, replace(cfg, loss=replace(cfg.loss, cross_warp=0.5, cross_warp_from=3))


def test_partner_draw():
    for n in (2, 3, 5):
        for view in range(n):
            ps = [cross_partner(0, it, view, n) for it in range(1, 200)]
            assert all(0 <= p < n and p != view for p in ps)
            assert len(set(ps)) == n - 1
    assert cross_partner(4, 17, 1, 5) == cross_partner(4, 17, 1, 5)


def test_fit_device_matches_host(device, case):
    host = fit_case(case, device, engine="host")
    dev = fit_case(case, device, engine="device")
    assert [it for it, *_ in host.history.cross_warp] == [5, 10, 15, 20, 21]
    for (_, lh, vh), (_, ld, vd) in zip(host.history.cross_warp, dev.history.cross_warp):
        assert lh > 0 and 0 < vh <= 1
        np.testing.assert_allclose([ld, vd], [lh, vh], rtol=1e-5)
    assert_engines_agree(device, host.state, dev.state, "cross_warp")


def test_fit_sums_the_loss_only_when_logged(device, case, monkeypatch):
    """cross_warp_rows (the loss's row sums and valid counts) runs once per logging iteration of
    the term, from read_cross_warp, never on the other iterations; the gradient kernel on each."""
    from reings.backends.opencl.trainer import DeviceTrainer

    stages = []
    launch = DeviceTrainer._launch

    def counting(self, stage, *a):
        stages.append(stage)
        return launch(self, stage, *a)

    monkeypatch.setattr(DeviceTrainer, "_launch", counting)
    res = fit_case(case, device, engine="device")
    logged = [it for it, *_ in res.history.cross_warp]
    assert logged == [5, 10, 15, 20, 21]
    assert stages.count("cross_warp_rows") == len(logged)
    assert stages.count("cross_warp") == case[2].iterations - case[2].loss.cross_warp_from + 1


def test_fit_off_never_calls_the_term_and_on_changes_the_result(device, case, monkeypatch):
    scene, init, cfg = case
    on = fit_case(case, device).state.params["means"]
    off_cfg = replace(cfg, loss=replace(cfg.loss, cross_warp=0.0))
    from reings.backends.opencl.trainer import DeviceTrainer

    def boom(*a, **k):
        raise AssertionError("cross_warp called with weight 0")

    monkeypatch.setattr(DeviceTrainer, "cross_warp", boom)
    off = fit_case((scene, init, off_cfg), device)
    assert not off.history.cross_warp
    p = off.state.params["means"]
    assert p.shape != on.shape or np.abs(p - on).max() > 1e-5
    # weight 0 with any start is the default config's fit, bit for bit
    monkeypatch.undo()
    dflt = fit_case((scene, init, replace(cfg, loss=replace(cfg.loss, cross_warp=0.0, cross_warp_from=1))), device)
    np.testing.assert_array_equal(dflt.state.params["means"], p)


def test_fit_resume_is_bit_identical(device, case, tmp_path):
    """Stopped at 17, last checkpoint at 15: inside the term's span."""
    ref, res = assert_resumes_bit_identically(case, device, tmp_path, stop_at=17)
    assert [tuple(x) for x in res.history.cross_warp] == [tuple(x) for x in ref.history.cross_warp]
    assert ref.history.cross_warp


def _with_occlusion(case, tol):
    scene, init, cfg = case
    return scene, init, replace(cfg, loss=replace(cfg.loss, cross_warp_occlusion=tol))


def test_fit_occlusion_device_matches_host(device, case):
    """With the occlusion test on, both engines give the same fit (bit for bit on PoCL) and the
    same history, whose rows carry the occluded fraction; the partner render is its own phase;
    the result differs from the fit without the test."""
    occl = _with_occlusion(case, 0.02)
    prof: dict = {}
    host = fit_case(occl, device, engine="host", profile=prof)
    dev = fit_case(occl, device, engine="device")
    assert [it for it, *_ in host.history.cross_warp] == [5, 10, 15, 20, 21]
    assert all(len(row) == 4 for row in host.history.cross_warp)
    assert max(o for *_, o in host.history.cross_warp) > 0
    for (_, lh, vh, oh), (_, ld, vd, od) in zip(host.history.cross_warp, dev.history.cross_warp):
        assert lh > 0 and 0 < vh + oh <= 1
        np.testing.assert_allclose([ld, vd, od], [lh, vh, oh], rtol=1e-5)
    assert_engines_agree(device, host.state, dev.state, "cross_warp occlusion")
    assert prof["cross_warp_render"] > 0 and prof["cross_warp"] > 0
    off = fit_case(case, device, engine="host")
    assert len(off.state) != len(host.state) or np.abs(off.state.params["means"] - host.state.params["means"]).max() > 0


def test_fit_occlusion_off_is_the_fit_without_it(device, case, monkeypatch):
    """Tolerance 0: no partner render, no held depth, the fit of before the option bit for bit
    (the same config). A tolerance no depth can exceed: the partner is rendered and held on every
    iteration of the term, one forward more each, and still the fit is the same bit for bit: the
    extra render moves nothing (no draw, no statistic, no frame the pass uses)."""
    from reings.backends.opencl.trainer import DeviceTrainer

    calls = {"forward": 0, "hold_depth": 0}
    for name in calls:
        orig = getattr(DeviceTrainer, name)

        def counted(self, *a, _orig=orig, _name=name, **k):
            calls[_name] += 1
            return _orig(self, *a, **k)

        monkeypatch.setattr(DeviceTrainer, name, counted)
    ref = fit_case(case, device, engine="device")
    forwards = calls["forward"]
    assert calls["hold_depth"] == 0
    big = fit_case(_with_occlusion(case, 1e30), device, engine="device")
    span = case[2].iterations - case[2].loss.cross_warp_from + 1
    assert calls["hold_depth"] == span and calls["forward"] == 2 * forwards + span
    assert_same_state(ref.state, big.state, True, "tolerance 1e30 vs 0")
    np.testing.assert_array_equal(big.history.loss, ref.history.loss)
    assert [tuple(r) for r in big.history.cross_warp] == [(*r, 0.0) for r in ref.history.cross_warp]


def test_fit_occlusion_partner_takes_the_pass_drop(device, case, monkeypatch):
    """With DropGaussian on, the partner's render (the forward whose frame hold_depth keeps) drops
    the same Gaussians as the training view's render right after it: the mask of the iteration
    (docs/method.md §12: both depths of one dropped model)."""
    from reings.backends.opencl.trainer import DeviceTrainer

    calls = []
    fwd, hold = DeviceTrainer.forward, DeviceTrainer.hold_depth

    def forward(self, *a, **k):
        calls.append(("forward", k.get("drop")))
        return fwd(self, *a, **k)

    def hold_depth(self, fr):
        calls.append(("hold_depth", None))
        return hold(self, fr)

    monkeypatch.setattr(DeviceTrainer, "forward", forward)
    monkeypatch.setattr(DeviceTrainer, "hold_depth", hold_depth)
    scene, init, cfg = _with_occlusion(case, 0.02)
    fit_case((scene, init, replace(cfg, loss=replace(cfg.loss, drop_gamma=0.3))), device, engine="device")
    at = [i for i, (name, _) in enumerate(calls) if name == "hold_depth"]
    assert len(at) == cfg.iterations - cfg.loss.cross_warp_from + 1
    for i in at:
        (before, partner), (after, training) = calls[i - 1], calls[i + 1]
        assert before == after == "forward" and partner is not None and partner is training


def test_fit_occlusion_resume_is_bit_identical(device, case, tmp_path):
    """With the occlusion test on: stopped at 17, last checkpoint at 15, inside the term's span."""
    ref, res = assert_resumes_bit_identically(_with_occlusion(case, 0.02), device, tmp_path, stop_at=17)
    assert [tuple(x) for x in res.history.cross_warp] == [tuple(x) for x in ref.history.cross_warp]
    assert ref.history.cross_warp and all(len(x) == 4 for x in ref.history.cross_warp)


def test_bad_weight_is_refused(case):
    scene, init, cfg = case
    for name in ("cross_warp", "cross_warp_occlusion"):
        for bad in (-1.0, float("nan"), float("inf")):
            with pytest.raises(ValueError, match=name):
                fit_case((scene, init, replace(cfg, loss=replace(cfg.loss, **{name: bad}))), "reference")
# }}}


def test_options_and_settings():
    from reings.cli import build_parser, config_from_args
    from reings.config import RunConfig
    from reings.evaluate import _ABSENT_WHEN_OFF
    from reings.pipeline import run_settings

    c = config_from_args(build_parser().parse_args(["run", "--cross-warp", "0.1", "--cross-warp-start", "0.25",
                                                    "--cross-warp-occlusion", "0.05"]))
    assert c.cross_warp == 0.1 and c.cross_warp_start == 0.25 and c.cross_warp_occlusion == 0.05
    assert config_from_args(build_parser().parse_args(["run"])).cross_warp is None  # absent: the recipe's
    assert config_from_args(build_parser().parse_args(["run", "--cross-warp", "0"])).cross_warp == 0.0
    assert config_from_args(build_parser().parse_args(["run", "--cross-warp", "none"])).cross_warp is None
    assert RunConfig().cross_warp is None and RunConfig().cross_warp_start == 0.0
    assert RunConfig().cross_warp_occlusion == 0.0
    s = run_settings(RunConfig(depth_prior="none", cross_warp=0).resolved(), "llff")
    assert not {"cross_warp", "cross_warp_start", "cross_warp_occlusion"} & set(s)  # absent when off
    s = run_settings(RunConfig().resolved(), "llff")  # the stereo prior: off by default
    assert not {"cross_warp", "cross_warp_start", "cross_warp_occlusion"} & set(s)
    s = run_settings(RunConfig(depth_prior="none").resolved(), "llff")  # the default without a prior
    assert s["cross_warp"] == 0.15 and "cross_warp_start" not in s and "cross_warp_occlusion" not in s
    s = run_settings(RunConfig(depth_prior="none", cross_warp=0.2).resolved(), "llff")
    assert s["cross_warp"] == 0.2 and "cross_warp_start" not in s and "cross_warp_occlusion" not in s
    s = run_settings(RunConfig(depth_prior="none", cross_warp_start=0.5, cross_warp_occlusion=0.05).resolved(), "llff")
    assert s["cross_warp"] == 0.15 and s["cross_warp_start"] == 0.5 and s["cross_warp_occlusion"] == 0.05
    assert "cross_warp" not in run_settings(RunConfig(depth_prior="none").resolved(), "dtu")
    assert "cross_warp" not in run_settings(RunConfig(depth_prior="none", recipe="dtu").resolved(), "llff")
    assert run_settings(RunConfig(cross_warp=0.1).resolved(), "dtu")["cross_warp"] == 0.1  # given: it wins
    for method in ("dngaussian", "3dgs"):
        for w in (None, 0.1):
            assert "cross_warp" not in run_settings(RunConfig(method=method, depth_prior="none",
                                                              cross_warp=w).resolved(), "llff")
    assert "cross_warp_occlusion" not in run_settings(RunConfig(cross_warp_occlusion=0.1).resolved(), "llff")
    assert "cross_warp" in _ABSENT_WHEN_OFF and "cross_warp_occlusion" in _ABSENT_WHEN_OFF
    with pytest.raises(ValueError, match="cross_warp"):
        RunConfig(cross_warp=-0.5)
    with pytest.raises(ValueError, match="cross_warp_start"):
        RunConfig(cross_warp_start=1.0)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="cross_warp_occlusion"):
            RunConfig(cross_warp_occlusion=bad)


def test_default_rule():
    """RunConfig.cross_warp = none (pipeline.cross_warp_of): 0.15 for the reings fits of the 'llff'
    family without a depth prior, 0 for 'dtu', with any prior, and for the baselines; a value given
    wins in the reings fits, 0 included; the baselines never take one."""
    from reings.config import RunConfig
    from reings.pipeline import NO_PRIOR_BY_FAMILY, cross_warp_of

    assert {f: r.get("cross_warp", 0.0) for f, r in NO_PRIOR_BY_FAMILY.items()} == {"llff": 0.15, "dtu": 0.0}
    for family in ("llff", "dtu"):
        for prior in ("none", "off", "no", "None", "stereo", "stereo:sgm_p1=0.2", "exact", "onnx:model.onnx"):
            for method in ("reings", "reings-no-ehps", "dngaussian", "3dgs"):
                cfg = RunConfig(method=method, depth_prior=prior)
                on = cfg.method == "reings" and family == "llff" and prior.lower() in ("none", "off", "no")
                assert cross_warp_of(cfg, family) == (0.15 if on else 0.0), (family, prior, method)
                for w in (0.0, 0.3):  # given: the reings fits take it, the baselines never
                    want = w if cfg.method == "reings" else 0.0
                    assert cross_warp_of(RunConfig(method=method, depth_prior=prior, cross_warp=w), family) == want


def test_make_run_has_no_term():
    """`make run` (`reings run --preset quick`, no --data: the procedural scene, the stereo prior)
    resolves the term to 0: no cross_warp in its settings nor in its fits' recipe."""
    from reings.cli import build_parser, config_from_args
    from reings.pipeline import cross_warp_of, recipe_family, run_settings

    cfg = config_from_args(build_parser().parse_args(["run", "--preset", "quick", "--out", "o", "--overwrite"]))
    cfg = cfg.resolved()
    assert cfg.data is None and cfg.cross_warp is None and cfg.depth_prior == "stereo"
    assert cross_warp_of(cfg, recipe_family(cfg.recipe, "procedural")) == 0.0
    assert "cross_warp" not in run_settings(cfg, "procedural")


def test_eval_tag_and_reuse_check(tmp_path):
    """`reings eval`: a finished LLFF reings run without a prior from before the default (no
    cross_warp in its settings) differs from what the defaults ask now, one with it does not; the
    DTU family's is unchanged; the table's tag names the weight and the occlusion tolerance."""
    import json

    from reings.config import RunConfig
    from reings.evaluate import _setting_tag, _settings_differ
    from reings.pipeline import run_settings

    cfg = RunConfig(depth_prior="none")
    for kind, on in (("llff", True), ("dtu", False)):
        now = json.loads(json.dumps(run_settings(cfg.resolved(), kind)))
        assert ("cross_warp" in now) == on
        old = {k: v for k, v in now.items() if k != "cross_warp"}
        for name, config in (("old", old), ("now", now)):
            (tmp_path / kind / name).mkdir(parents=True)
            (tmp_path / kind / name / "metrics.json").write_text(json.dumps({"config": config}))
        assert ("cross_warp" in _settings_differ(str(tmp_path / kind / "old" / "metrics.json"), cfg, kind)) == on
        assert _settings_differ(str(tmp_path / kind / "now" / "metrics.json"), cfg, kind) == ""
    occl = RunConfig(depth_prior="none", cross_warp_occlusion=0.05)
    assert "cross_warp_occlusion" in _settings_differ(str(tmp_path / "llff" / "now" / "metrics.json"), occl, "llff")
    s = run_settings(RunConfig(depth_prior="none", cross_warp_start=0.25, cross_warp_occlusion=0.05).resolved(),
                     "llff")
    tag = _setting_tag({"preset": "paper", "method": "reings", "depth_prior": "none", "config": s})
    assert "cross 0.15 from 0.25 occl 0.05" in tag


def test_notes_only_for_a_value_given():
    """pipeline.option_notes: the default (none) never logs a note, on the baselines, on the 'dtu'
    family or with one training view; a value given that a fit ignores does."""
    from reings.config import RunConfig
    from reings.pipeline import option_notes as all_notes

    def option_notes(cfg, family, n):  # those on the cross_warp options (others: final_prune's on a baseline)
        return [t for t in all_notes(cfg, family, n) if "cross_warp" in t]

    for method in ("reings", "dngaussian", "3dgs"):
        for family in ("llff", "dtu"):
            for prior in ("none", "stereo"):
                for n in (1, 3):
                    assert not option_notes(RunConfig(method=method, depth_prior=prior), family, n), (
                        method, family, prior, n)
    for method in ("dngaussian", "3dgs"):
        assert option_notes(RunConfig(method=method, cross_warp=0.1), "llff", 3) == [
            "cross_warp applies to the reings fits only; ignored"]
        assert not option_notes(RunConfig(method=method, cross_warp=0), "llff", 3)
    assert option_notes(RunConfig(cross_warp=0.1), "llff", 1) == [
        "cross_warp needs a partner view: 1 training view; ignored"]
    assert not option_notes(RunConfig(cross_warp=0.1), "llff", 2)
    # the start and the occlusion test: a note where the term is off, none where the default turns it on
    assert not option_notes(RunConfig(depth_prior="none", cross_warp_start=0.5), "llff", 3)
    assert option_notes(RunConfig(depth_prior="none", cross_warp_start=0.5), "dtu", 3) == [
        "cross_warp_start without cross_warp; ignored"]
    assert option_notes(RunConfig(depth_prior="none", cross_warp=0, cross_warp_occlusion=0.1), "llff", 3) == [
        "cross_warp_occlusion without cross_warp; ignored"]


def test_run_recipe_takes_the_default():
    """RunContext.run_recipe: the resolved weight (cross_warp_of) reaches the reings fits'
    LossConfig, from the first iteration; 0 elsewhere."""
    from reings.config import RunConfig
    from reings.pipeline import RunContext, baseline_recipe, cross_warp_of

    for method in ("reings", "dngaussian"):
        for family in ("llff", "dtu"):
            for prior, w in (("none", None), ("stereo", None), ("none", 0.0), ("stereo", 0.3)):
                cfg = RunConfig(method=method, depth_prior=prior, cross_warp=w, view_warp=0.0)
                ctx = RunContext.__new__(RunContext)
                ctx.cfg, ctx.family, ctx.smooth_w = cfg, family, None
                r = ctx.run_recipe(baseline_recipe("dngaussian", 100, 0, family))
                want = cross_warp_of(cfg, family)
                assert r.loss.cross_warp == want, (method, family, prior, w)
                assert r.loss.cross_warp_from == 1
                if method == "reings" and w is None:
                    assert want == (0.15 if (family, prior) == ("llff", "none") else 0.0)


def test_a_run_records_the_resolved_weight(device, caplog):
    """metrics.json: the weight the fits use at the top level and in `config`, only when on; no
    note for the default on a baseline."""
    import logging

    import reings

    scene = reings.make_procedural_scene(n_views=8, width=64, height=48, supersample=1)
    kw = dict(scene=scene, iterations=(2, 2, 2), device=device, with_lpips=False, eval_every=0, quiet=True,
              views=3, extent="frusta", depth_prior="none")
    m = reings.run(method="reings", **kw).metrics
    assert m["cross_warp"] == 0.15 and m["config"]["cross_warp"] == 0.15 and m["recipe"] == "llff"
    assert "cross_warp_occlusion" not in m and "cross_warp_start" not in m["config"]
    m = reings.run(method="reings", cross_warp=0.0, **kw).metrics
    assert "cross_warp" not in m and "cross_warp" not in m["config"]
    with caplog.at_level(logging.INFO, logger="reings"):
        m = reings.run(method="dngaussian", **{**kw, "iterations": 2}).metrics
    assert "cross_warp" not in m and "cross_warp" not in m["config"]
    assert not [r for r in caplog.records if "cross_warp" in r.getMessage()]


def test_run_recipe_sets_the_term():
    """RunContext.run_recipe puts the weight and the start (fraction of the fit) into the reings
    fits' LossConfig, and nothing for the baselines."""
    from reings.config import RunConfig
    from reings.pipeline import RunContext, baseline_recipe

    for method, want in (("reings", 0.2), ("dngaussian", 0.0)):
        cfg = RunConfig(method=method, depth_prior="none", cross_warp=0.2, cross_warp_start=0.5, view_warp=0.0,
                        cross_warp_occlusion=0.03)
        ctx = RunContext.__new__(RunContext)
        ctx.cfg, ctx.family, ctx.smooth_w = cfg, "llff", None
        r = ctx.run_recipe(baseline_recipe("dngaussian", 100, 0))
        assert r.loss.cross_warp == want and r.loss.cross_warp_occlusion == (0.03 if want else 0.0)
        if want:
            assert r.loss.cross_warp_from == 50


_OCLGRIND_SCRIPT = """
import types
import numpy as np
import pyopencl as cl
from reings.backends import get_backend
from reings.types import Camera
h, w = 5, 7
rng = np.random.default_rng(0)
K = np.array([[7.0, 0, 3.5], [0, 7.0, 2.5], [0, 0, 1]])
ci = Camera(K, np.eye(4), w, h)
v = np.eye(4); v[0, 3] = -0.3
cj = Camera(K, v, w, h)
a = rng.uniform(0, 1, (h, w)).astype(np.float32); a[0, 0] = 0
d = (a * rng.uniform(1, 3, (h, w))).astype(np.float32); d[1, 0] = np.nan; d[1, 1] = -1
ii = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
ij = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
tr = get_backend("oclgrind").trainer([ii, ij], engine="device")
mf = cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR
fr = types.SimpleNamespace(width=w, height=h, camera=ci,
                           bufs={"out_depth": cl.Buffer(tr.handle.context, mf, hostbuf=d),
                                 "out_alpha": cl.Buffer(tr.handle.context, mf, hostbuf=a)})
g = tr._read(tr.cross_warp(fr, 0, 1, cj, 0.5, 0.01), (h, w), np.float32)
assert np.all(np.isfinite(g)) and g[0, 0] == 0 and g[1, 0] == 0 and g[1, 1] == 0
st = tr.read_cross_warp()
assert np.isfinite(st["loss"]) and 0 < st["valid_fraction"] < 1 and st["occluded_fraction"] == 0
# the occlusion test: the partner's depth held (a copy), nearer than most reprojected points
aj = np.ones((h, w), np.float32); aj[0] = 0.2
pf = types.SimpleNamespace(width=w, height=h, camera=cj,
                           bufs={"out_depth": cl.Buffer(tr.handle.context, mf, hostbuf=(aj * 1.2).astype(np.float32)),
                                 "out_alpha": cl.Buffer(tr.handle.context, mf, hostbuf=aj)})
held = tr.hold_depth(pf)
g = tr._read(tr.cross_warp(fr, 0, 1, cj, 0.5, 0.01, occlusion=0.05, partner_depth=held), (h, w), np.float32)
assert np.all(np.isfinite(g))
st = tr.read_cross_warp()
assert np.isfinite(st["loss"]) and 0 < st["occluded_fraction"] < 1
print("ok")
"""


@pytest.mark.oclgrind
def test_oclgrind_checks():
    """cross_warp_grad and cross_warp_rows, with invalid pixels, without and with the occlusion
    test (hold_depth's copies read), under Oclgrind's checks."""
    from oclgrind_util import check_script

    check_script(_OCLGRIND_SCRIPT)
