"""The float64 reference checks itself: central finite differences vs every hand-written backward.

Criterion (Warp gradcheck style), per element:  |AD - FD| <= FD_ATOL_REL * max|FD| + FD_RTOL * |FD|
with FD_STEP = 1e-6 (tests/tolerances.py). The backward is exact, so only FD noise is allowed.

Scenes are hand-built away from discontinuities, and every FD evaluation re-checks that it stayed
there: the *signature* (radii, tile rects, per-pixel last contributor, Jacobian-clamp masks, colour
clamp signs, α-clamp set) must be identical at x+h and x-h, otherwise the test fails saying the scene
is too close to a discontinuity (never a silently wrong FD).

Test-only smooth cutoff: most tests pass `alpha_min=0` to the rasterizer, which removes the 1/255
skip (a jump of 1/255 in α); `test_render_vjp_fd_real_cutoff` keeps the real 1/255 on a scene whose
pairs all stay above it (checked through the signature's blended-pair count).

Quaternions: the loss is invariant to |q|, so AD must have no radial part (checked) and the tangent
parts of AD and FD are compared.
"""
from __future__ import annotations

import numpy as np
import pytest

from cases import make_camera, rotation_viewmat
from reings.backends import reference as ref
from reings.backends.base import ALPHA_MAX, ALPHA_MIN, Projected
from reings.types import FIELDS, SH_COUNTS
from tolerances import FD_ATOL_REL, FD_RTOL, FD_STEP


# ------------------------------------------------------------------------------------------------
# FD machinery
# ------------------------------------------------------------------------------------------------
def fd_of(loss, x: np.ndarray, set_x, sig=None, h: float = FD_STEP, name: str = "x") -> np.ndarray:
    """Central differences of loss(set_x(x')) over every element of x. `sig(set_x(x'))`, if given,
    must not change between +h, -h and the base point."""
    base_sig = None if sig is None else sig(set_x(x))
    out = np.zeros_like(x)
    for i in range(x.size):
        vals = []
        for s in (+h, -h):
            y = x.copy()
            y.flat[i] += s
            arg = set_x(y)
            if sig is not None:
                got = sig(arg)
                for k in base_sig:
                    if not np.array_equal(got[k], base_sig[k]):
                        raise AssertionError(f"FD scene too close to a discontinuity: {k!r} changed "
                                             f"when perturbing {name}[{np.unravel_index(i, x.shape)}] by {s:+g}")
            vals.append(loss(arg))
        out.flat[i] = (vals[0] - vals[1]) / (2 * h)
    return out


def check_fd(ad, fd, name):
    ad, fd = np.asarray(ad, np.float64), np.asarray(fd, np.float64)
    assert ad.shape == fd.shape, name
    assert np.all(np.isfinite(ad)), f"{name}: non-finite AD"
    scale = np.abs(fd).max() if fd.size else 0.0
    tol = FD_ATOL_REL * scale + FD_RTOL * np.abs(fd)
    err = np.abs(ad - fd)
    if fd.size and not np.all(err <= tol + 1e-300):
        i = int(np.argmax(err - tol))
        idx = np.unravel_index(i, fd.shape)
        raise AssertionError(f"{name}: {(err > tol).sum()}/{fd.size} beyond tolerance; worst {idx}: "
                             f"AD={ad.flat[i]!r} FD={fd.flat[i]!r} |err|={err.flat[i]:.3e} "
                             f"tol={tol.flat[i]:.3e} (max|FD|={scale:.3e})")


def tangent(q, v):
    """Remove the component of v [N, 4] along q [N, 4]."""
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    return v - qn * np.sum(qn * v, axis=1, keepdims=True)


def check_params_fd(ad: ref.Params64, p: ref.Params64, loss, sig, fields=FIELDS, label=""):
    for f in fields:
        x = np.array(getattr(p, f), dtype=np.float64)
        fd = fd_of(loss, x, lambda y, f=f: p.replace(**{f: y}), sig, name=f)
        a = getattr(ad, f)
        if f == "quats":
            qn = x / np.linalg.norm(x, axis=1, keepdims=True)
            radial = np.sum(qn * a, axis=1)
            # exact zero up to float64 round-off of the projection q̂ (q̂·v_q̂)
            assert np.all(np.abs(radial) <= 1e-12 * max(np.abs(a).max(), 1.0)), f"{label}quats radial {radial}"
            check_fd(tangent(x, a), tangent(x, fd), f"{label}quats (tangent)")
        else:
            check_fd(a, fd, f"{label}{f}")


# ------------------------------------------------------------------------------------------------
# scenes (float64 parameters, built away from discontinuities)
# ------------------------------------------------------------------------------------------------
W, H = 40, 24  # 3 x 2 tiles, not a multiple of 16


def fd_camera(viewmat=None):
    return make_camera(W, H, f=40.0, cx=20.0, cy=12.0,
                       viewmat=rotation_viewmat((0.05, -0.08, 0.03), (0.05, -0.02, 0.1)) if viewmat is None else viewmat)


def _cam_to_world(cam, pts):
    V = cam.viewmat
    return (np.asarray(pts, np.float64) - V[:3, 3]) @ V[:3, :3]


def fd_scene(cam, sh_degree=3, seed=0, clamp=False, colour_clamp=True):
    """4-5 Gaussians: three large ones covering all tiles, one small one covering some tiles, and
    (clamp=True) one large Gaussian off-screen with the Jacobian clamp active on x and y."""
    rng = np.random.default_rng(seed)
    cam_pts = [[-0.4, 0.1, 3.5], [0.5, -0.2, 3.9], [0.1, 0.25, 4.3], [0.21, 0.07, 3.1]]
    ls = [np.log([0.9, 1.1, 0.8]), np.log([1.2, 0.7, 1.0]), np.log([1.0, 1.0, 0.6]), np.log([0.12, 0.2, 0.15])]
    if clamp:
        cam_pts.append([3.2, -2.1, 3.0])  # x/z = 1.07 > 0.65, y/z = -0.7 < -0.51: both clamped
        ls.append(np.log([1.8, 1.5, 1.6]))
    n = len(cam_pts)
    k = SH_COUNTS[sh_degree]
    sh = rng.normal(0, 0.3, (n, k, 3))
    sh[:, 0, :] = rng.uniform(0.2, 1.0, (n, 3))
    if colour_clamp:
        sh[1, 0, 0] = -4.0  # red of Gaussian 1 clamped at 0 (zero gradient there)
    return ref.Params64(means=_cam_to_world(cam, cam_pts), quats=rng.normal(size=(n, 4)),
                        log_scales=np.array(ls), opacity_logits=rng.uniform(-1.0, 0.8, n), sh=sh)


def cotangents(seed=1):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(H, W, 3)), rng.normal(size=(H, W)), rng.normal(size=(H, W))


def render_signature(cam, bg, near=0.01, override=None, alpha_min=0.0, drop=None):
    """What must not change inside one FD evaluation (see module docstring)."""
    def sig(p):
        proj, aux = ref._project(p, cam, near, override, drop, alpha_min)  # the rect render_loss bins
        bins = ref.bin(proj, cam.width, cam.height)
        out = ref.rasterize_fwd(proj, bins, cam.width, cam.height, bg, True, alpha_min)
        return dict(radii=proj.radii, tile_rect=proj.tile_rect, last=out.last,
                    mask_x=aux["mask_x"] | ~aux["ok"], mask_y=aux["mask_y"] | ~aux["ok"],
                    colour_sign=aux["raw"] >= 0, order=bins.gid_from_isect,
                    evaluated=out.evaluated_pairs, clamped=_alpha_clamped(proj, bins, cam, alpha_min))
    return sig


def _alpha_clamped(proj, bins, cam, alpha_min):
    tiles_x, tiles_y = ref.tile_grid(cam.width, cam.height)
    out = []
    for t in range(tiles_x * tiles_y):
        s, e = bins.tile_ranges[t]
        ii, jj = ref._tile_pixels(t, tiles_x, cam.width, cam.height)
        r = ref._tile_blend(proj, np.asarray(bins.gid_from_isect[s:e], np.int64), ii, jj, alpha_min)
        out.append(np.count_nonzero(r["blended"] & (r["raw"] > ALPHA_MAX)))
        out.append(np.count_nonzero(r["blended"]))
    return np.array(out)


def render_loss(cam, vr, vd, va, bg, near=0.01, override=None, alpha_min=0.0, drop=None):
    def loss(p):
        _, _, out, _ = ref.render64(p, cam, bg, near, override, False, alpha_min, drop)
        return np.sum(vr * out.rgb) + np.sum(vd * out.depth) + np.sum(va * out.alpha)
    return loss


BG = (0.3, 0.6, 0.1)


# ------------------------------------------------------------------------------------------------
# building blocks
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_basis_jacobian_fd(degree):
    rng = np.random.default_rng(degree)
    d = rng.normal(size=(5, 3))
    _, J = ref.sh_basis(d, degree, with_jacobian=True)
    for k in range(SH_COUNTS[degree]):
        fd = fd_of(lambda x: ref.sh_basis(x, degree)[:, k].sum(), d, lambda y: y, name="dir")
        check_fd(J[:, k, :], fd, f"d basis_{k} / d dir")


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_color_vjp_fd(degree):
    rng = np.random.default_rng(10 + degree)
    n = 6
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sh = rng.normal(size=(n, SH_COUNTS[degree], 3))
    sh[0, 0, :] = -100.0  # clamped colours
    v = rng.normal(size=(n, 3))
    v_sh, v_d = ref.sh_to_color_vjp(sh, d, v)

    def colour(sh_, d_):  # sh_to_color without renormalising d (the VJP is for the raw basis)
        basis = ref.sh_basis(d_, degree)
        return np.maximum(np.einsum("nk,nkc->nc", basis, sh_) + 0.5, 0.0)
    check_fd(v_sh, fd_of(lambda s: np.sum(v * colour(s, d)), sh, lambda y: y, name="sh"), "v_sh")
    check_fd(v_d, fd_of(lambda x: np.sum(v * colour(sh, x)), d, lambda y: y, name="dir"), "v_dir")
    assert np.all(v_sh[0] == 0.0)


def test_quat_rotmat_vjp_fd():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(4, 4))
    v = rng.normal(size=(4, 3, 3))
    ad = ref.quat_to_rotmat_vjp(q, v)
    fd = fd_of(lambda x: np.sum(v * ref.quat_to_rotmat(x)), q, lambda y: y, name="q")
    check_fd(ad, fd, "quat_to_rotmat_vjp (polynomial, all 4 directions)")


# ------------------------------------------------------------------------------------------------
# project_bwd, via each Projected output field
# ------------------------------------------------------------------------------------------------
PROJ_FIELDS = ("means2d", "conics", "depths", "colors", "opacities")
GRAD_OF = dict(means2d="v_means2d", conics="v_conics", depths="v_depths", colors="v_colors",
               opacities="v_opacities")


def _proj_cotangents(n, which, seed=5):
    rng = np.random.default_rng(seed)
    shapes = dict(means2d=(n, 2), conics=(n, 3), depths=(n,), colors=(n, 3), opacities=(n,))
    return {f: (rng.normal(size=shapes[f]) * (10.0 if f == "conics" else 1.0) if f in which else np.zeros(shapes[f]))
            for f in PROJ_FIELDS}


@pytest.mark.parametrize("which", [(f,) for f in PROJ_FIELDS] + [PROJ_FIELDS], ids=lambda w: "+".join(w))
@pytest.mark.parametrize("override", [None, 0.8], ids=["sigmoid", "override"])
def test_project_bwd_fd(which, override):
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=2, clamp=True)
    n = len(p)
    v = _proj_cotangents(n, which)
    grads = ref.RasterGrads(**{GRAD_OF[f]: v[f] for f in PROJ_FIELDS})
    proj = ref.project_fwd(p, cam, 0.01, override)
    assert np.all(proj.radii > 0)
    _, aux = ref._project(p, cam, 0.01, override)
    assert not aux["mask_x"][4] and not aux["mask_y"][4], "the clamp Gaussian must be clamped"
    ad = ref.project_bwd(p, cam, proj, grads, 0.01, override)

    def loss(pp):
        pr = ref.project_fwd(pp, cam, 0.01, override)
        return sum(np.sum(v[f] * getattr(pr, f)) for f in PROJ_FIELDS)

    def sig(pp):
        pr, ax = ref._project(pp, cam, 0.01, override)
        return dict(radii=pr.radii, mask_x=ax["mask_x"], mask_y=ax["mask_y"], colour_sign=ax["raw"] >= 0)
    check_params_fd(ad, p, loss, sig, label=f"project_bwd[{'+'.join(which)}] ")
    if override is not None:
        assert np.all(ad.opacity_logits == 0.0)


# ------------------------------------------------------------------------------------------------
# rasterize_bwd, per output, bins held fixed
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("output", ["rgb", "depth", "alpha", "all"])
def test_rasterize_bwd_fd(output):
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=0, clamp=True)
    proj = ref.project_fwd(p, cam)
    bins = ref.bin(proj, W, H)
    vr, vd, va = cotangents(2)
    vr = vr if output in ("rgb", "all") else np.zeros_like(vr)
    vd = vd if output in ("depth", "all") else np.zeros_like(vd)
    va = va if output in ("alpha", "all") else np.zeros_like(va)
    out = ref.rasterize_fwd(proj, bins, W, H, BG, alpha_min=0.0)
    g = ref.rasterize_bwd(proj, bins, out, vr, vd, va, W, H, BG, alpha_min=0.0)

    def with_field(f, y):
        d = {k: getattr(proj, k) for k in ("means2d", "conics", "depths", "radii", "tile_rect", "colors", "opacities")}
        d[f] = y
        return Projected(**d)

    def loss(pr):
        o = ref.rasterize_fwd(pr, bins, W, H, BG, alpha_min=0.0)
        return np.sum(vr * o.rgb) + np.sum(vd * o.depth) + np.sum(va * o.alpha)

    def sig(pr):
        o = ref.rasterize_fwd(pr, bins, W, H, BG, alpha_min=0.0)
        return dict(last=o.last, clamped=_alpha_clamped(pr, bins, cam, 0.0))

    for f in PROJ_FIELDS:
        x = np.array(getattr(proj, f), np.float64)
        fd = fd_of(loss, x, lambda y, f=f: with_field(f, y), sig, name=f)
        check_fd(getattr(g, GRAD_OF[f]), fd, f"rasterize_bwd[{output}] {GRAD_OF[f]}")


def test_rasterize_bwd_fd_alpha_clamp_and_early_stop():
    """Opaque stack: some pairs hit the 0.99 clamp (zero gradient, FD agrees away from the kink)
    and pixels stop early (entries at and after the stop get nothing)."""
    cam = fd_camera(np.eye(4))
    pts = [[-0.0375, -0.0375, 3.0], [0.02, 0.01, 3.3], [-0.01, 0.02, 3.6], [0.0, -0.02, 3.9]]
    p = ref.Params64(means=np.array(pts), quats=np.tile([1.0, 0.1, -0.2, 0.05], (4, 1)),
                     log_scales=np.log(np.full((4, 3), 0.4)), opacity_logits=np.array([6.0, 3.3, 3.5, 3.0]),
                     sh=np.random.default_rng(0).uniform(0.1, 1, (4, 1, 3)))
    proj = ref.project_fwd(p, cam)
    bins = ref.bin(proj, W, H)
    out = ref.rasterize_fwd(proj, bins, W, H, BG, alpha_min=0.0)
    lens = np.diff(bins.tile_ranges, axis=1)[:, 0]
    assert (out.final_T < 1e-3).any() and (out.last < lens.max()).any(), "scene must stop early somewhere"
    assert _alpha_clamped(proj, bins, cam, 0.0)[0::2].sum() > 0, "scene must hit the α clamp"
    vr, vd, va = cotangents(4)
    g = ref.rasterize_bwd(proj, bins, out, vr, vd, va, W, H, BG, alpha_min=0.0)
    loss = lambda pr: (lambda o: np.sum(vr * o.rgb) + np.sum(vd * o.depth) + np.sum(va * o.alpha))(  # noqa: E731
        ref.rasterize_fwd(pr, bins, W, H, BG, alpha_min=0.0))

    def sig(pr):
        o = ref.rasterize_fwd(pr, bins, W, H, BG, alpha_min=0.0)
        return dict(last=o.last, clamped=_alpha_clamped(pr, bins, cam, 0.0))

    for f in PROJ_FIELDS:
        x = np.array(getattr(proj, f), np.float64)
        d = {k: getattr(proj, k) for k in ("means2d", "conics", "depths", "radii", "tile_rect", "colors", "opacities")}
        fd = fd_of(loss, x, lambda y, f=f: Projected(**{**d, f: y}), sig, name=f)
        check_fd(getattr(g, GRAD_OF[f]), fd, f"rasterize_bwd[stack] {GRAD_OF[f]}")


# ------------------------------------------------------------------------------------------------
# end to end: render_vjp for every raw field
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_render_vjp_fd(degree):
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=degree, seed=degree)
    vr, vd, va = cotangents(degree)
    ad = ref.render_vjp64(p, cam, vr, vd, va, BG, alpha_min=0.0)
    check_params_fd(ad, p, render_loss(cam, vr, vd, va, BG), render_signature(cam, BG), label=f"sh{degree} ")


def test_render_vjp_fd_jacobian_clamp():
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=1, seed=7, clamp=True)
    _, aux = ref._project(p, cam, 0.01, None)
    assert not aux["mask_x"][4] and not aux["mask_y"][4] and aux["ok"][4]
    vr, vd, va = cotangents(7)
    ad = ref.render_vjp64(p, cam, vr, vd, va, BG, alpha_min=0.0)
    check_params_fd(ad, p, render_loss(cam, vr, vd, va, BG), render_signature(cam, BG), label="clamp ")


def test_render_vjp_fd_opacity_override():
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=1, seed=8, clamp=True)
    vr, vd, va = cotangents(8)
    ad = ref.render_vjp64(p, cam, vr, vd, va, BG, opacity_override=0.7, alpha_min=0.0)
    assert np.all(ad.opacity_logits == 0.0)
    check_params_fd(ad, p, render_loss(cam, vr, vd, va, BG, override=0.7),
                    render_signature(cam, BG, override=0.7), label="override ")


def test_render_vjp_fd_real_cutoff():
    """The real 1/255 skip, on big Gaussians whose pairs all stay above it (signature-checked)."""
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=0, seed=9, colour_clamp=False)
    p = p.replace(means=p.means[:3], quats=p.quats[:3], log_scales=p.log_scales[:3] + 0.6,
                  opacity_logits=p.opacity_logits[:3] + 1.0, sh=p.sh[:3])
    vr, vd, va = cotangents(9)
    ad = ref.render_vjp64(p, cam, vr, vd, va, BG)
    check_params_fd(ad, p, render_loss(cam, vr, vd, va, BG, alpha_min=ALPHA_MIN),
                    render_signature(cam, BG, alpha_min=ALPHA_MIN), label="cutoff ")


def test_render_vjp_backend_wrapper_matches_float64():
    """ReferenceBackend.render_vjp (float32 API) = render_vjp64 on the float32-rounded inputs."""
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=2, seed=2)
    g = p.to_gaussians()
    vr, vd, va = (a.astype(np.float32) for a in cotangents(3))
    be = ref.ReferenceBackend()
    got = be.render_vjp(g, cam, vr, vd, va, BG, grad_fields=("means", "sh"))
    want = ref.render_vjp64(g, cam, vr, vd, va, BG)
    for f in FIELDS:
        exp = getattr(want, f).astype(np.float32) if f in ("means", "sh") else 0.0 * getattr(want, f)
        np.testing.assert_array_equal(getattr(got, f), exp.astype(np.float32), err_msg=f)
