"""Real-data checks; they run when REINGS_DATA points at the shared data folder and skip otherwise."""
from __future__ import annotations

import os

import numpy as np
import pytest

from reings.data import few_shot_split, load_scene

ROOT = os.environ.get("REINGS_DATA")
pytestmark = [pytest.mark.data,
              pytest.mark.skipif(not (ROOT and os.path.isdir(ROOT)), reason="REINGS_DATA not set")]


def _path(*p):
    d = os.path.join(ROOT, *p)
    if not os.path.isdir(d):
        pytest.skip(f"{d} not present")
    return d


def _reproject(cam, P):
    Xc = P @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    uv = (Xc @ cam.K.T)[:, :2] / Xc[:, 2:3]
    inside = (Xc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return uv, Xc[:, 2], inside


@pytest.fixture(scope="module")
def fern():
    return load_scene(_path("llff", "fern"))


def test_fern_loads_and_points_reproject(fern):
    sc = fern
    assert sc.kind == "llff" and len(sc) == 20 and sc.images[0].shape == (378, 504, 3)
    assert sc.names[0] == "image000.png"
    np.testing.assert_allclose(sc.cameras[0].K, [[3260.5263 / 8, 0, 252], [0, 3260.5263 / 8, 189], [0, 0, 1]],
                               atol=1e-3)
    # the dataset's own COLMAP points (same world frame) land in front of and inside every view
    for cam in sc.cameras:
        _, _, inside = _reproject(cam, sc.points)
        assert inside.mean() > 0.9
    # and at the right place: the points' colours match the pixels they project to
    cam, im = sc.cameras[5], sc.images[5]
    uv, z, inside = _reproject(cam, sc.points)
    iu, iv = uv[inside, 0].astype(int), uv[inside, 1].astype(int)
    err = np.abs(im[iv, iu] - sc.point_colors[inside]).mean()
    shuffled = np.abs(im[iv, iu] - sc.point_colors[inside][np.random.default_rng(0).permutation(inside.sum())]).mean()
    assert err < 0.6 * shuffled, (err, shuffled)
    # near/far bounds of poses_bounds.npy bracket the points' depths (LLFF computes them so)
    assert np.percentile(z[z > 0], 1) >= sc.bounds[5, 0] * 0.9 and np.percentile(z[z > 0], 99) <= sc.bounds[5, 1] * 1.1


@pytest.mark.parametrize("scene,n,splits", [
    ("fern", 20, {2: [1, 19], 3: [1, 10, 19], 4: [1, 6, 13, 19]}),
    ("flower", 34, {2: [1, 33], 3: [1, 17, 33], 4: [1, 11, 22, 33]}),
])
def test_llff_splits(scene, n, splits):
    sc = load_scene(_path("llff", scene), load_points=False)
    assert len(sc) == n
    for k, train in splits.items():
        tr, te = few_shot_split(sc, k)
        assert tr == train and te == list(range(0, n, 8))


def test_nex_trex():
    sc = load_scene(_path("llff_nex", "trex"))
    assert sc.kind == "llff_nex" and len(sc) == 55 and sc.images[0].shape == (376, 501, 3)
    assert abs(sc.cameras[0].cx - 501.6537 / 2) < 0.01 and abs(sc.cameras[0].cy - 367.5507 * 376 / 751) < 0.01
    fr = [_reproject(c, sc.points)[2].mean() for c in sc.cameras[::6]]
    assert min(fr) > 0.8


def test_dtu_scan24():
    cv2 = pytest.importorskip("cv2")
    sc = load_scene(_path("dtu", "scan24"))
    assert sc.kind == "dtu" and len(sc) == 49 and sc.images[0].shape == (300, 400, 3)
    assert sc.masks is not None and sc.masks[0].shape == (300, 400) and 0.2 < sc.masks[0].mean() < 0.9
    # K at 1600x1200 (docs/data.md "Test data and models": [[2892.33, 0, 823.21], [0, 2883.18, 619.07]]) divided by 4
    np.testing.assert_allclose(sc.cameras[0].K[:2, :3] * 4, [[2892.33, 0, 823.21], [0, 2883.18, 619.07]], atol=0.02)
    # same decomposition as OpenCV's
    d = np.load(os.path.join(_path("dtu", "scan24"), "cameras_sphere.npz"))
    P = (d["world_mat_7"] @ d["scale_mat_7"])[:3]
    K, R, t = cv2.decomposeProjectionMatrix(P)[:3]
    np.testing.assert_allclose(sc.cameras[7].viewmat[:3, :3], R, atol=1e-9)
    np.testing.assert_allclose(sc.cameras[7].center, (t[:3] / t[3]).ravel(), atol=1e-6)
    # cameras look at the unit sphere (the object)
    for cam in sc.cameras:
        uv, z, inside = _reproject(cam, np.zeros((1, 3)))
        assert inside[0] and sc.bounds[0, 0] < z[0] < sc.bounds[0, 1] + 1
    tr, te = few_shot_split(sc, 3)
    assert tr == [25, 22, 28] and len(te) == 25


@pytest.mark.slow
def test_fern_sfm_extent_from_training_views(fern):
    pytest.importorskip("pycolmap")
    from reings.data.sfm import sfm_extent

    tr, _ = few_shot_split(fern, 3)
    ext = sfm_extent(fern.subset(tr))
    assert ext.method == "sfm" and ext.n_points > 200
    # the training-view box sits inside the full-view COLMAP cloud's extent
    lo_full, hi_full = fern.points.min(0), fern.points.max(0)
    assert np.all(ext.lo >= lo_full - 1) and np.all(ext.hi <= hi_full + 1)
