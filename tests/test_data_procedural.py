"""The built-in procedural scene: deterministic, and its depths are exact and multi-view consistent."""
from __future__ import annotations

import time

import numpy as np

from reings.data import make_procedural_scene
from reings.data.procedural import _WALL_Z

DEPTH_REL_TOL = 1e-4  # float32 depth maps; exact geometry otherwise


def _backproject(cam, depth):
    H, W = depth.shape
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1)
    Xc = (pix @ np.linalg.inv(cam.K).T) * depth.ravel()[:, None]
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    return (Xc - t) @ R


def test_shapes_and_determinism():
    a = make_procedural_scene(n_views=4, width=40, height=30, seed=3, supersample=1)
    b = make_procedural_scene(n_views=4, width=40, height=30, seed=3, supersample=1)
    c = make_procedural_scene(n_views=4, width=40, height=30, seed=4, supersample=1)
    assert a.kind == "procedural" and len(a) == 4 and a.names[0] == "view000.png"
    assert a.images[0].shape == (30, 40, 3) and a.images[0].dtype == np.float32
    assert a.depths[0].shape == (30, 40) and np.all(np.isfinite(a.depths[0])) and a.depths[0].min() > 0
    for x, y in zip(a.images, b.images):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a.images, c.images))
    assert 0 <= a.images[0].min() and a.images[0].max() <= 1 and a.images[0].std() > 0.05
    np.testing.assert_allclose(a.bounds[:, 0], [d.min() for d in a.depths])


def test_default_is_fast():
    t = time.perf_counter()
    sc = make_procedural_scene()
    dt = time.perf_counter() - t
    assert len(sc) == 24 and sc.images[0].shape == (150, 200, 3)
    assert dt < 20.0, dt  # ~3-5 s on one free core; generous for shared CI machines


def test_depth_is_exact_geometry():
    sc = make_procedural_scene(n_views=3, width=80, height=60, supersample=1)
    X = _backproject(sc.cameras[0], sc.depths[0])
    # nothing is below the ground or behind the wall; both planes are hit exactly
    assert X[:, 1].min() > -1e-4 and X[:, 2].max() < _WALL_Z + 1e-3
    assert np.mean(np.abs(X[:, 1]) < 1e-3) > 0.2  # ground pixels
    assert np.mean(np.abs(X[:, 2] - _WALL_Z) < 1e-3) > 0.1  # wall pixels


def test_depth_consistent_across_views():
    """Back-project view 0, project into view 2: where visible, view 2's depth agrees."""
    sc = make_procedural_scene(n_views=3, width=80, height=60, supersample=1)
    X = _backproject(sc.cameras[0], sc.depths[0])
    cam = sc.cameras[2]
    Xc = X @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    uv = (Xc @ cam.K.T)[:, :2] / Xc[:, 2:3]
    # bilinear lookup between pixel centres (at +0.5)
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ok = (x0 >= 0) & (x0 < cam.width - 1) & (y0 >= 0) & (y0 < cam.height - 1)
    x0, y0, fx, fy = x0[ok], y0[ok], (x - np.floor(x))[ok], (y - np.floor(y))[ok]
    D = sc.depths[2]
    d_other = ((D[y0, x0] * (1 - fx) + D[y0, x0 + 1] * fx) * (1 - fy)
               + (D[y0 + 1, x0] * (1 - fx) + D[y0 + 1, x0 + 1] * fx) * fy)
    rel = np.abs(d_other - Xc[ok, 2]) / Xc[ok, 2]
    # occlusions and depth edges aside, within a pixel's footprint on smooth surfaces
    assert np.median(rel) < 1e-3
    assert np.mean(rel < 0.01) > 0.75  # views 30 degrees apart: the rest is occlusion
    # occlusion makes view 2 see *nearer* surfaces; seeing farther happens only at depth edges
    nearest4 = np.minimum(np.minimum(D[y0, x0], D[y0, x0 + 1]), np.minimum(D[y0 + 1, x0], D[y0 + 1, x0 + 1]))
    assert np.mean(nearest4 > Xc[ok, 2] * 1.01) < 0.002
