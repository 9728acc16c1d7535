"""SfM extent from the training views: robust box, frusta fallback, known-pose triangulation."""
from __future__ import annotations

import numpy as np
import pytest

from reings import Camera
from reings.data import Scene, few_shot_split, make_procedural_scene
from reings.data.procedural import look_at
from reings.data.sfm import frusta_extent, robust_aabb, sfm_extent


def test_robust_aabb_order_statistics():
    p = np.zeros((200, 3))
    p[:, 0] = np.arange(200)
    p[:, 1] = -np.arange(200)
    lo, hi, k = robust_aabb(p, trim=20)
    assert k == 20
    np.testing.assert_array_equal(lo, [19, -180, 0])  # 20th smallest
    np.testing.assert_array_equal(hi, [180, -19, 0])  # 20th largest
    lo, hi, k = robust_aabb(p[:50], trim=20)  # few points: k = n // 10
    assert k == 5 and lo[0] == 4 and hi[0] == 45
    with pytest.raises(ValueError):
        robust_aabb(np.zeros((0, 3)))


def test_frusta_extent_single_and_pair():
    K = np.array([[10, 0, 10], [0, 10, 5], [0, 0, 1.0]])  # 20x10 image: x/z in [-1, 1], y/z in [-.5, .5]
    cam = Camera(K, np.eye(4), 20, 10)
    lo, hi, how = frusta_extent([cam], [[1, 2]])
    assert how == "intersection"
    np.testing.assert_allclose(lo, [-2, -1, 1], atol=1e-9)
    np.testing.assert_allclose(hi, [2, 1, 2], atol=1e-9)
    # a second camera shifted right by 1: the overlap starts at x = 0 on the near plane ... within both
    V = np.eye(4)
    V[0, 3] = -1.0  # centre at x = +1
    lo2, hi2, how2 = frusta_extent([cam, Camera(K, V, 20, 10)], [[1, 2], [1, 2]])
    assert how2 == "intersection"
    assert lo2[0] >= -1 - 1e-6 and hi2[0] <= 2 + 1e-6  # inside both: x in [1 - 2, 0 + 2]
    assert lo2[2] >= 1 - 1e-6 and hi2[2] <= 2 + 1e-6
    # disjoint frusta fall back to the union box
    V3 = np.eye(4)
    V3[0, 3] = -100.0
    *_, how3 = frusta_extent([cam, Camera(K, V3, 20, 10)], [[1, 2], [1, 2]])
    assert how3 == "union"


@pytest.fixture(scope="module")
def proc():
    return make_procedural_scene(n_views=24, width=200, height=150, supersample=2)


def test_sfm_points_lie_on_the_true_surfaces(proc):
    pytest.importorskip("pycolmap")
    pytest.importorskip("cv2")
    tr, _ = few_shot_split(proc, 3)
    train = proc.subset(tr)
    ext = sfm_extent(train)
    assert ext.method == "sfm" and ext.n_points >= 100, ext.n_points
    assert np.all(ext.lo <= ext.hi) and np.all(ext.lo_all <= ext.lo) and np.all(ext.hi <= ext.hi_all)
    # each point's depth in training view 0 matches the exact depth at its pixel (where visible)
    cam, depth = train.cameras[0], train.depths[0]
    Xc = ext.points @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    uv = (Xc @ cam.K.T)[:, :2] / Xc[:, 2:3]
    iu, iv = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok = (Xc[:, 2] > 0) & (iu >= 0) & (iu < cam.width) & (iv >= 0) & (iv < cam.height)
    assert ok.mean() > 0.8
    rel = np.abs(depth[iv[ok], iu[ok]] - Xc[ok, 2]) / Xc[ok, 2]
    assert np.median(rel) < 0.02, np.median(rel)
    assert np.mean(rel < 0.05) > 0.8


def test_sfm_fallback_to_frusta(proc):
    pytest.importorskip("pycolmap")
    pytest.importorskip("cv2")
    tr, _ = few_shot_split(proc, 2)
    blank = proc.subset(tr)
    blank.images = [np.full_like(im, 0.5) for im in blank.images]  # no features at all
    ext = sfm_extent(blank)
    assert ext.method == "frusta" and ext.n_points == 0 and ext.num_sfm_points == 0
    lo, hi, _ = frusta_extent(blank.cameras, blank.bounds)
    np.testing.assert_allclose(ext.lo, lo)
    np.testing.assert_allclose(ext.hi, hi)
    with pytest.raises(ValueError, match="only 0 points"):
        sfm_extent(blank, fallback=False)
    blank.bounds = None
    with pytest.raises(ValueError, match="no near/far"):
        sfm_extent(blank)


def test_sfm_needs_two_views():
    K = np.array([[10, 0, 4], [0, 10, 3], [0, 0, 1.0]])
    sc = Scene([np.zeros((6, 8, 3))], [Camera(K, look_at([0, 0, -5], [0, 0, 0]), 8, 6)], ["a"])
    with pytest.raises(ValueError, match="at least 2"):
        sfm_extent(sc)
