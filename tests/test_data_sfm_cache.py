"""The on-disk cache of `sfm_extent`: hit, key sensitivity, corrupt files, reuse without pycolmap."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from reings.data import few_shot_split, make_procedural_scene
from reings.data import sfm as sfm_mod
from reings.data.sfm import load_cached_extent, sfm_cache_dir, sfm_cache_key, sfm_extent, store_cached_extent


@pytest.fixture(scope="module")
def train():
    scene = make_procedural_scene(n_views=12, width=200, height=150, supersample=1)
    tr, _ = few_shot_split(scene, 3)
    return scene.subset(tr)


def _same(a, b):
    np.testing.assert_array_equal(a.lo, b.lo)
    np.testing.assert_array_equal(a.hi, b.hi)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.colors, b.colors)
    assert (a.method, a.trim, a.num_sfm_points, a.num_matched_pairs) == (b.method, b.trim, b.num_sfm_points, b.num_matched_pairs)


def test_cache_dir_follows_env(monkeypatch, tmp_path):
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path))
    assert sfm_cache_dir() == tmp_path / "sfm"


def test_key_depends_on_pixels_cameras_and_settings(train):
    s = {"trim": 20}
    k = sfm_cache_key(train, s)
    assert k == sfm_cache_key(train, dict(s))
    assert k != sfm_cache_key(train, {"trim": 21})
    imgs = [im.copy() for im in train.images]
    imgs[0][0, 0, 0] += 1e-3
    assert k != sfm_cache_key(dataclasses.replace(train, images=imgs), s)
    cams = list(train.cameras)
    vm = cams[1].viewmat.copy()
    vm[0, 3] += 1e-6
    cams[1] = dataclasses.replace(cams[1], viewmat=vm)
    assert k != sfm_cache_key(dataclasses.replace(train, cameras=cams), s)


def test_roundtrip_and_corrupt_file(tmp_path):
    ext = sfm_mod.SfmExtent(np.array([0.0, 1, 2]), np.array([3.0, 4, 5]), "sfm", np.random.rand(7, 3),
                            np.random.rand(7, 3).astype(np.float32), np.zeros(3), np.ones(3) * 9, 3, 2, 7)
    p = store_cached_extent("ab" * 32, ext, tmp_path)
    got = load_cached_extent("ab" * 32, tmp_path)
    assert got is not None and got.cached
    _same(ext, got)
    np.testing.assert_array_equal(got.lo_all, ext.lo_all)
    assert load_cached_extent("cd" * 32, tmp_path) is None  # another key
    frusta = dataclasses.replace(ext, method="frusta", points=np.zeros((0, 3)), colors=np.zeros((0, 3), np.float32),
                                 lo_all=None, hi_all=None)
    store_cached_extent("ef" * 32, frusta, tmp_path)
    got = load_cached_extent("ef" * 32, tmp_path)
    assert got.method == "frusta" and got.lo_all is None and got.points.shape == (0, 3)
    p.write_bytes(b"not an npz")  # unreadable: treated as a miss
    assert load_cached_extent("ab" * 32, tmp_path) is None
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".tmp-")]  # no temp files left behind


def test_sfm_extent_cached_and_reused_without_pycolmap(train, tmp_path, monkeypatch):
    pytest.importorskip("pycolmap")
    pytest.importorskip("cv2")
    first = sfm_extent(train, cache_dir=tmp_path)
    assert not first.cached and first.method == "sfm" and first.n_points >= 50  # real triangulated points
    assert len(list(tmp_path.glob("sfm-*.npz"))) == 1

    calls = []
    real = sfm_mod._sfm_extent_uncached
    monkeypatch.setattr(sfm_mod, "_sfm_extent_uncached", lambda *a, **k: calls.append(1) or real(*a, **k))
    second = sfm_extent(train, cache_dir=tmp_path)
    assert second.cached and not calls  # no COLMAP run
    _same(first, second)

    # a machine without pycolmap: the cached result is used as is
    monkeypatch.setattr(sfm_mod, "_have_pycolmap", lambda: False)
    third = sfm_extent(train, cache_dir=tmp_path)
    assert third.cached and not calls
    _same(first, third)

    # ... and without a cached result: the frusta fallback with a warning, and nothing stored
    empty = tmp_path / "empty"
    with pytest.warns(RuntimeWarning, match="pycolmap is not installed"):
        fb = sfm_extent(train, cache_dir=empty)
    assert fb.method == "frusta" and fb.note == "no pycolmap"
    assert not list(empty.glob("sfm-*.npz"))
    with pytest.raises(Exception, match="pycolmap is not installed"):
        sfm_extent(train, cache_dir=empty, fallback=False)

    # another setting is another key: recomputed (here: the no-pycolmap fallback)
    with pytest.warns(RuntimeWarning):
        other = sfm_extent(train, cache_dir=tmp_path, trim=5)
    assert not other.cached


def test_corrupt_cache_file_is_recomputed(train, tmp_path):
    pytest.importorskip("pycolmap")
    pytest.importorskip("cv2")
    a = sfm_extent(train, cache_dir=tmp_path)
    (f,) = tmp_path.glob("sfm-*.npz")
    f.write_bytes(f.read_bytes()[:100])  # truncated
    b = sfm_extent(train, cache_dir=tmp_path)
    assert not b.cached
    _same(a, b)
    assert load_cached_extent(sfm_cache_key(train, _settings_of(train)), tmp_path) is not None  # rewritten


def _settings_of(train):
    return {"min_points": sfm_mod.DEFAULT_MIN_POINTS, "trim": sfm_mod.DEFAULT_TRIM, "fallback": True,
            "max_features": 8192, "max_reproj_error": 4.0, "min_tri_angle": 1.5, "peak_threshold": None,
            "guided_matching": True}
