"""ReInGS re-initialisation (reings.reinit: ivps_points and its pieces) against the procedural
scene's exact geometry: back-projection (float64, exact), the hard-render depth normalisation,
the pixel-centre convention, colour order and the SH DC encoding of the IVPS points."""
from __future__ import annotations

import numpy as np
import pytest

from reings import render
from reings.data import make_procedural_scene
from reings.data.procedural import _layout, _Noise, _trace
from reings.config import ReInGSConfig
from reings.reinit import backproject_pixels, ehps_init, ivps_points, ivps_view_scores, stereo_seed_points
from reings.train import SH_C0, gaussians_from_points
from reings.types import Gaussians

SEED = 0
W, H = 64, 48
BG, NEAR = (0.0, 0.0, 0.0), 0.01


@pytest.fixture(scope="module")
def scene():
    return make_procedural_scene(n_views=3, width=W, height=H, seed=SEED, supersample=1)


def _trace_depth(cam, X):
    """Camera-space z at which the ray from the camera centre through world points X [n, 3] first
    hits the procedural scene (float64, the scene's own ray tracer)."""
    rng = np.random.default_rng(SEED)  # make_procedural_scene's draws, in its order
    layout, noise = _layout(rng), _Noise(rng)
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    Xc = X @ R.T + t
    d_cam = Xc / Xc[:, 2:3]  # camera z = 1, as the scene's depth rays
    _, tz = _trace(cam.center, d_cam @ R, layout, noise, depth_only=True)
    return Xc[:, 2], tz


def _surface_gaussians(cam, depth, colors, opacity=0.99, footprint=0.5):
    """One isotropic Gaussian per pixel on the true surface: scale = footprint pixels at its depth."""
    idx = np.arange(cam.width * cam.height)
    X = backproject_pixels(cam, idx, depth.ravel().astype(np.float64))
    g = gaussians_from_points(X.astype(np.float32), colors.reshape(-1, 3), 0, np.random.default_rng(0), opacity=opacity)
    s = footprint * depth.ravel() / cam.fx
    return Gaussians(g.means, g.quats, np.repeat(np.log(s)[:, None], 3, 1), g.opacity_logits, g.sh)


def test_depths_are_camera_z_and_backprojection_is_exact(scene):
    """The procedural depths are camera-space z (not ray distance); back-projecting pixel centres
    with them lands exactly on the traced surface and reprojects to the same pixel centre."""
    rng = np.random.default_rng(1)
    for cam, depth in zip(scene.cameras, scene.depths):
        idx = rng.choice(W * H, size=200, replace=False)
        z = depth.ravel()[idx].astype(np.float64)
        X = backproject_pixels(cam, idx, z)
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        Xc = X @ R.T + t
        v, u = np.divmod(idx, W)
        np.testing.assert_allclose(Xc[:, 0] / Xc[:, 2] * cam.fx + cam.cx, u + 0.5, atol=1e-9)
        np.testing.assert_allclose(Xc[:, 1] / Xc[:, 2] * cam.fy + cam.cy, v + 0.5, atol=1e-9)
        np.testing.assert_allclose(Xc[:, 2], z, rtol=1e-12)
        pz, tz = _trace_depth(cam, X)
        # the point is where the scene's ray hits: only the float32 storage of the depth differs
        np.testing.assert_allclose(pz, tz, rtol=1e-6)
        # ray distance would differ by |(x, y, 1)| >= 1, up to ~1.15 at these corners (60 deg FoV)
        ray = np.linalg.norm(Xc / Xc[:, 2:3], axis=1)
        assert ray.max() > 1.05


def test_renderer_pixel_centre_convention(scene, device):
    """A tiny Gaussian back-projected from pixel (u, v)'s centre renders symmetric about that pixel."""
    cam, depth = scene.cameras[0], scene.depths[0]
    u0, v0 = 23, 17
    z = float(depth[v0, u0])
    X = backproject_pixels(cam, np.array([v0 * W + u0]), np.array([z]))
    s = 0.7 * z / cam.fx  # 0.7 px
    g = Gaussians(X.astype(np.float32), np.array([[1, 0, 0, 0]], np.float32), np.full((1, 3), np.log(s), np.float32),
                  np.array([3.0], np.float32), np.full((1, 1, 3), 1.0, np.float32))
    a = render(g, cam, device, BG, NEAR).alpha
    assert np.unravel_index(np.argmax(a), a.shape) == (v0, u0)
    np.testing.assert_allclose(a[v0, u0 - 1], a[v0, u0 + 1], rtol=1e-3)
    np.testing.assert_allclose(a[v0 - 1, u0], a[v0 + 1, u0], rtol=1e-3)


def _neighbourhood_range(depth, r):
    pad = np.pad(depth, r, mode="edge")
    win = np.stack([pad[dy:dy + depth.shape[0], dx:dx + depth.shape[1]]
                    for dy in range(2 * r + 1) for dx in range(2 * r + 1)])
    return win.min(0), win.max(0)


@pytest.mark.parametrize("hard_opacity", [0.99, 0.5])
def test_hard_depth_over_alpha_of_surface_gaussians_is_the_true_depth(scene, device, hard_opacity):
    """Gaussians on the true surface: IVPS's depth (hard render depth / hard alpha) is a convex
    combination of the true depths of the pixel's neighbours (the renderer's 0.3 px^2 low-pass makes
    each Gaussian reach ~2 px; with the hard opacity the nearer neighbour wins, so the median error is
    ~1% towards the camera, not 0); with hard opacity 0.5 the alpha is well below 1, so this also
    checks the division by alpha. The colours come back in RGB order through the SH DC encoding."""
    rc = ReInGSConfig(ivps_hard_opacity=hard_opacity, ivps_min_alpha=0.3)
    for cam, depth, img in zip(scene.cameras, scene.depths, scene.images):
        g = _surface_gaussians(cam, depth, img, footprint=0.3)
        np.testing.assert_allclose(0.5 + SH_C0 * g.sh[:, 0], img.reshape(-1, 3), atol=1e-6)
        score, d, info = ivps_view_scores(g, cam, None, rc, device, BG, NEAR)
        ok = info["valid"]
        assert ok.mean() > 0.99
        lo, hi = _neighbourhood_range(depth, 2)
        inside = (d >= lo * (1 - 1e-4)) & (d <= hi * (1 + 1e-4))
        assert inside[ok].mean() > 0.99, inside[ok].mean()
        rel = np.abs(d - depth) / depth
        assert np.median(rel[ok]) < 0.02, np.median(rel[ok])
        if hard_opacity < 0.9:  # un-normalised depth would be off by the missing alpha
            hard_alpha = render(g, cam, device, BG, NEAR, opacity_override=hard_opacity).alpha
            assert np.median(1 - hard_alpha[ok]) > 0.05
        rgb = render(g, cam, device, BG, NEAR).rgb
        mse = np.mean((np.clip(rgb, 0, 1) - img) ** 2)
        mse_bgr = np.mean((np.clip(rgb[..., ::-1], 0, 1) - img) ** 2)
        assert mse < 0.5 * mse_bgr and -10 * np.log10(mse) > 22, (mse, mse_bgr)


@pytest.mark.parametrize("ivps_depth", ["hard", "expected"])
def test_ivps_points_of_a_surface_model_lie_on_the_surface(scene, device, ivps_depth):
    """ivps_points on a model whose Gaussians sit on the surface: its points are on the surface
    (traced, float64) and carry the colour of the pixel they came from."""
    g = None
    for cam, depth, img in zip(scene.cameras, scene.depths, scene.images):
        gi = _surface_gaussians(cam, depth, img, footprint=0.3)
        g = gi if g is None else Gaussians(*(np.concatenate([a, b]) for a, b in zip(g.astuple(), gi.astuple())))
    rc = ReInGSConfig(ivps_depth=ivps_depth)
    pts, cols = ivps_points(g, scene, None, rc, device, BG, NEAR, np.random.default_rng(0))
    n = int(round(rc.ivps_fraction * W * H))
    assert pts.shape == (3 * n, 3) and cols.shape == (3 * n, 3)
    for k, (cam, img) in enumerate(zip(scene.cameras, scene.images)):
        P = pts[k * n:(k + 1) * n].astype(np.float64)
        pz, tz = _trace_depth(cam, P)
        rel = np.abs(pz - tz) / tz
        # the hard render's bias towards the nearer neighbour (see above); at 64x48 about 10% of
        # the pixels lie within ~2 px of a depth edge, where the hard depth blends both sides
        assert np.median(rel) < 0.02 and np.mean(rel < 0.05) > 0.8, (np.median(rel), np.mean(rel < 0.05))
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        Xc = P @ R.T + t
        u = np.floor(Xc[:, 0] / Xc[:, 2] * cam.fx + cam.cx).astype(int)
        v = np.floor(Xc[:, 1] / Xc[:, 2] * cam.fy + cam.cy).astype(int)
        np.testing.assert_allclose(cols[k * n:(k + 1) * n], img[v, u], atol=1e-6)


def test_faint_floaters_capture_the_hard_depth_not_the_expected_depth(scene, device):
    """The mechanism behind the quick preset's IVPS drop: a few faint (opacity 0.03) Gaussians in
    front of an opaque surface are invisible in the normal render but, forced to opacity 0.99, own
    the hard depth of Eq. 5; ReInGSConfig(ivps_depth="expected") back-projects to the surface."""
    cam, depth, img = scene.cameras[0], scene.depths[0], scene.images[0]
    surf = _surface_gaussians(cam, depth, img, footprint=0.3)
    rng = np.random.default_rng(2)
    idx = rng.choice(W * H, size=60, replace=False)  # faint blobs at 40% of the surface depth
    Xf = backproject_pixels(cam, idx, 0.4 * depth.ravel()[idx].astype(np.float64))
    s = 4.0 * 0.4 * depth.ravel()[idx] / cam.fx  # 4 px
    logit = np.log(0.03 / 0.97)
    fl = Gaussians(Xf.astype(np.float32), np.tile(np.float32([1, 0, 0, 0]), (60, 1)),
                   np.repeat(np.log(s)[:, None], 3, 1), np.full(60, logit, np.float32), np.zeros((60, 1, 3), np.float32))
    g = Gaussians(*(np.concatenate([a, b]) for a, b in zip(surf.astuple(), fl.astuple())))
    covered = render(fl, cam, device, BG, NEAR, opacity_override=0.99).alpha > 0.5
    assert covered.mean() > 0.3
    err = {}
    for mode in ("hard", "expected"):
        _, d, info = ivps_view_scores(g, cam, None, ReInGSConfig(ivps_depth=mode), device, BG, NEAR)
        err[mode] = np.median((np.abs(d - depth) / depth)[covered & info["valid"]])
    assert err["hard"] > 0.4 and err["expected"] < 0.1, err
    with pytest.raises(ValueError, match="ivps_depth"):
        ReInGSConfig(ivps_depth="median")


def test_stereo_seed_points_lie_on_the_surface_and_respect_the_confidence(scene):
    """stereo_seed_points with the exact depths as the prior: every point is on the traced surface,
    carries its pixel's colour, and comes from a pixel whose confidence is at least the threshold;
    at most fraction * H * W per view, and all qualifying pixels when fewer qualify."""
    rng = np.random.default_rng(3)
    confs = []
    for k in range(len(scene)):  # confidence 0 on the left half, a ramp on the right
        c = np.zeros((H, W), np.float32)
        c[:, W // 2:] = np.linspace(0.2, 1.0, W - W // 2)[None]
        confs.append(c if k != 1 else np.zeros_like(c))  # view 1: nothing confident
    pts, cols = stereo_seed_points(scene, scene.depths, confs, 0.4, 0.5, rng)
    n = int(round(0.4 * W * H))
    ok = int((confs[0] >= 0.5).sum())
    assert ok < n  # the threshold, not the fraction, limits this case
    assert pts.shape == (2 * ok, 3) and cols.shape == (2 * ok, 3)
    for k, cam in ((0, scene.cameras[0]), (1, scene.cameras[2])):
        P = pts[k * ok:(k + 1) * ok].astype(np.float64)
        pz, tz = _trace_depth(cam, P)
        np.testing.assert_allclose(pz, tz, rtol=1e-5)
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        Xc = P @ R.T + t
        u = np.floor(Xc[:, 0] / Xc[:, 2] * cam.fx + cam.cx).astype(int)
        v = np.floor(Xc[:, 1] / Xc[:, 2] * cam.fy + cam.cy).astype(int)
        assert (confs[0][v, u] >= 0.5).all()
        np.testing.assert_allclose(cols[k * ok:(k + 1) * ok], scene.images[2 * k][v, u], atol=1e-6)
    few, _ = stereo_seed_points(scene, scene.depths, confs, 0.01, 0.5, np.random.default_rng(0))
    assert len(few) == 2 * int(round(0.01 * W * H))
    # drawn with p ~ confidence: the confident right end wins over the left end of the ramp
    P = few[: len(few) // 2].astype(np.float64)
    R, t = scene.cameras[0].viewmat[:3, :3], scene.cameras[0].viewmat[:3, 3]
    Xc = P @ R.T + t
    u = np.floor(Xc[:, 0] / Xc[:, 2] * scene.cameras[0].fx + scene.cameras[0].cx).astype(int)
    assert u.min() >= W // 2
    none, _ = stereo_seed_points(scene, scene.depths, [np.zeros((H, W), np.float32)] * 3, 0.5, 0.5, rng)
    assert none.shape == (0, 3)


def test_ehps_with_seeds_keeps_its_points_and_adds_the_coloured_seeds():
    rc = ReInGSConfig(min_init_points=100)
    lo, hi = np.zeros(3), np.ones(3)
    g0 = ehps_init(lo, hi, rc, 1, np.random.default_rng(5))
    seeds = (np.array([[0.47, 0.52, 0.51], [0.2, 0.3, 0.4]], np.float32), np.array([[1, 0, 0], [0, 0.5, 1]], np.float32))
    g1 = ehps_init(lo, hi, rc, 1, np.random.default_rng(5), seeds)
    assert len(g1) == len(g0) + 2
    np.testing.assert_array_equal(g1.means[:len(g0)], g0.means)
    np.testing.assert_array_equal(g1.sh[:len(g0)], g0.sh)
    np.testing.assert_allclose(g1.sh[len(g0):, 0] * SH_C0 + 0.5, seeds[1], atol=1e-6)
    np.testing.assert_array_equal(g1.means[len(g0):], seeds[0])
    # the 3-NN scales see every point: a seed inside the grid gets a scale from its grid neighbours
    others = np.delete(g1.means, len(g0), axis=0).astype(np.float64)
    d = np.sort(np.linalg.norm(others - seeds[0][0], axis=1))[:3]
    assert d[0] > 0
    np.testing.assert_allclose(np.exp(g1.log_scales[len(g0)]), np.sqrt(np.mean(d ** 2)), rtol=1e-4)
