"""Few-shot protocols and the structural leakage guard (`few_shot_split` + `Scene.subset`)."""
from __future__ import annotations

import numpy as np
import pytest

from reings import Camera
from reings.data import DTU_EXCLUDED, Scene, few_shot_split
from reings.data.procedural import look_at


def _scene(n, kind="llff", names=None, seed=0):
    rng = np.random.default_rng(seed)
    K = np.array([[10, 0, 4], [0, 10, 3], [0, 0, 1.0]])
    cams = [Camera(K, look_at([0.1 * i, 0, -5], [0, 0, 0]), 8, 6) for i in range(n)]
    ims = [np.full((6, 8, 3), i / max(n, 1), np.float32) for i in range(n)]  # image i is filled with i/n
    names = names or [f"image{i:03d}.png" for i in range(n)]
    masks = [np.full((6, 8), i, np.float32) for i in range(n)]
    bounds = np.stack([np.arange(n) + 1.0, np.arange(n) + 100.0], 1)
    pts = rng.normal(size=(50, 3))
    return Scene(ims, cams, names, kind=kind, masks=masks, bounds=bounds, points=pts,
                 points_from_all_views=True)


@pytest.mark.parametrize("n,k,train,test", [
    (20, 2, [1, 19], [0, 8, 16]), (20, 3, [1, 10, 19], [0, 8, 16]), (20, 4, [1, 6, 13, 19], [0, 8, 16]),
    (34, 2, [1, 33], [0, 8, 16, 24, 32]), (34, 3, [1, 17, 33], [0, 8, 16, 24, 32]),
    (34, 4, [1, 11, 22, 33], [0, 8, 16, 24, 32]),
    (55, 3, [1, 28, 54], list(range(0, 55, 8))),  # trex (docs/method.md §4.1: 1/28/54)
    (62, 3, [1, 30, 61], list(range(0, 62, 8))),  # horns 1/30/61
    (25, 3, [1, 12, 23], [0, 8, 16, 24]),  # orchids 1/12/23 (pool round-half-even)
])
def test_llff_protocol(n, k, train, test):
    assert few_shot_split(_scene(n), k) == (train, test)


def test_llff_sorts_by_name():
    names = [f"image{i:03d}.png" for i in range(20)]
    perm = np.random.default_rng(1).permutation(20)
    sc = _scene(20, names=[names[p] for p in perm])
    tr, te = few_shot_split(sc, 3)
    assert [sc.names[i] for i in tr] == ["image001.png", "image010.png", "image019.png"]
    assert sorted(sc.names[i] for i in te) == ["image000.png", "image008.png", "image016.png"]


def test_dtu_protocol():
    sc = _scene(49, kind="dtu")
    tr, te = few_shot_split(sc, 3)
    assert tr == [25, 22, 28]
    assert te == [1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45, 46, 47]
    assert few_shot_split(sc, 9)[0] == [25, 22, 28, 40, 44, 48, 0, 8, 13]
    assert not set(te) & set(DTU_EXCLUDED)
    with pytest.raises(ValueError, match="49 views"):
        few_shot_split(_scene(20, kind="dtu"), 3)
    # an explicit protocol overrides the kind
    assert few_shot_split(sc, 3, protocol="llff")[0] == [1, 23, 47]


def test_bad_n_views():
    with pytest.raises(ValueError):
        few_shot_split(_scene(20), 0)
    with pytest.raises(ValueError):
        few_shot_split(_scene(20), 18)
    with pytest.raises(ValueError, match="unknown protocol"):
        few_shot_split(_scene(20), 3, protocol="nope")


def test_subset_holds_only_training_views():
    """The leakage guard: the train scene's arrays all come from training views."""
    n = 20
    sc = _scene(n)
    tr, te = few_shot_split(sc, 3)
    sub = sc.subset(tr)
    assert len(sub) == 3 and sub.names == [sc.names[i] for i in tr]
    # every per-view array carries the identity of a training view and nothing else
    for j, i in enumerate(tr):
        assert np.all(sub.images[j] == np.float32(i / n))
        assert np.all(sub.masks[j] == i)
        np.testing.assert_array_equal(sub.cameras[j].viewmat, sc.cameras[i].viewmat)
    np.testing.assert_array_equal(sub.bounds, sc.bounds[tr])
    # the full-view sparse points are derived from every view, test views included: dropped
    assert sub.points is None and sub.point_colors is None and not sub.points_from_all_views
    # nothing reachable from the subset holds a test view's value
    test_vals = {np.float32(i / n) for i in te}
    for arr in sub.images:
        assert not (set(np.unique(arr)) & test_vals)
    for v in sub.meta.values():
        assert isinstance(v, (str, int, float, bool))
    # copies, not views: editing the subset does not touch the full scene
    sub.images[0][:] = -1
    assert sc.images[tr[0]].min() >= 0
    # opt-in keeps the full-view points, flagged
    sub2 = sc.subset(tr, keep_full_view_points=True)
    assert sub2.points is not None and sub2.points_from_all_views


def test_subset_errors():
    sc = _scene(5)
    with pytest.raises(IndexError):
        sc.subset([7])
    with pytest.raises(ValueError, match="repeated"):
        sc.subset([1, 1])


def test_procedural_follows_llff_rule():
    from reings.data import make_procedural_scene

    sc = make_procedural_scene(n_views=10, width=16, height=12, supersample=1)
    tr, te = few_shot_split(sc, 3)
    assert te == [0, 8] and tr == [1, 5, 9]
