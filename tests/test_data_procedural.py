"""The built-in procedural scene: deterministic, and its depths are exact and multi-view consistent."""
from __future__ import annotations

import errno
import os
import time

import numpy as np
import pytest

from reings.data import make_procedural_scene
from reings.data import procedural as P
from reings.data.procedural import _WALL_Z

DEPTH_REL_TOL = 1e-4  # float32 depth maps; exact geometry otherwise


def _backproject(cam, depth):
    H, W = depth.shape
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1)
    Xc = (pix @ np.linalg.inv(cam.K).T) * depth.ravel()[:, None]
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    return (Xc - t) @ R


@pytest.fixture
def no_memo(monkeypatch):
    """An empty in-process memo (restored afterwards): every call below renders or reads the disk."""
    monkeypatch.setattr(P, "_MEMO", {})
    return P._MEMO


def test_shapes_and_determinism(no_memo):
    a = make_procedural_scene(n_views=4, width=40, height=30, seed=3, supersample=1)
    no_memo.clear()  # b ray traced again, not a's memo
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


def test_default_is_fast(no_memo):
    t = time.perf_counter()  # the ray tracing itself: no memo, no disk cache
    sc = make_procedural_scene()
    dt = time.perf_counter() - t
    assert len(sc) == 24 and sc.images[0].shape == (150, 200, 3)
    assert dt < 20.0, dt  # 6-12 s on one core of the machines measured (docs/data.md); generous for shared CI


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


SMALL = dict(n_views=3, width=40, height=30, seed=2, supersample=1)


def _same_scene(a, b):
    assert a.names == b.names and len(a) == len(b)
    for f in ("images", "depths"):
        for x, y in zip(getattr(a, f), getattr(b, f)):
            assert x.dtype == y.dtype == np.float32
            np.testing.assert_array_equal(x, y)
    for ca, cb in zip(a.cameras, b.cameras):
        np.testing.assert_array_equal(ca.K, cb.K)
        np.testing.assert_array_equal(ca.viewmat, cb.viewmat)
    np.testing.assert_array_equal(a.bounds, b.bounds)


def _no_render(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("rendered again")
    monkeypatch.setattr(P, "_render_views", fail)


def test_disk_cache_gives_the_rendered_bits(no_memo, tmp_path, monkeypatch):
    """The first disk_cache call renders and writes one file; a later process (here: an empty
    memo, the renderer disabled) reads the same bits from it. Without disk_cache nothing is written."""
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path))
    fresh = make_procedural_scene(**SMALL)
    assert not (tmp_path / "procedural").exists()
    no_memo.clear()
    first = make_procedural_scene(**SMALL, disk_cache=True)
    files = list((tmp_path / "procedural").iterdir())
    assert [f.name for f in files] == [P.procedural_cache_path(next(iter(no_memo))).name]
    no_memo.clear()
    with monkeypatch.context() as m:
        _no_render(m)
        cached = make_procedural_scene(**SMALL, disk_cache=True)
    _same_scene(fresh, first)
    _same_scene(fresh, cached)
    # every call returns its own writeable copies
    cached.images[0][:] = 0.0
    cached.depths[0][:] = 0.0
    again = make_procedural_scene(**SMALL, disk_cache=True)
    _same_scene(fresh, again)


def test_the_memo_returns_copies_without_rendering(no_memo, monkeypatch):
    a = make_procedural_scene(**SMALL)
    _no_render(monkeypatch)
    a.images[1][:] = 1.0
    b = make_procedural_scene(**SMALL)
    assert b.images[1].flags.writeable and not np.array_equal(a.images[1], b.images[1])
    with pytest.raises(AssertionError, match="rendered again"):
        make_procedural_scene(**{**SMALL, "seed": 3})  # other settings: not the memo's


def test_the_memo_keeps_the_most_recently_used_settings(no_memo):
    tiny = {**SMALL, "width": 8, "height": 6}
    for seed in range(P._MEMO_SIZE):
        make_procedural_scene(**{**tiny, "seed": seed})
    make_procedural_scene(**{**tiny, "seed": 0})  # used again: the most recent now
    make_procedural_scene(**{**tiny, "seed": 99})  # evicts the least recently used, seed 1
    assert len(no_memo) == P._MEMO_SIZE
    assert [k[3] for k in no_memo] == [*range(2, P._MEMO_SIZE), 0, 99]


def test_the_disk_cache_keeps_the_most_recently_used_files(no_memo, tmp_path, monkeypatch):
    import time

    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(P, "_DISK_KEEP", 2)
    folder = tmp_path / "procedural"
    folder.mkdir()
    stale, fresh = folder / ".tmp-killed.npz", folder / ".tmp-writing.npz"
    stale.write_bytes(b"x")
    fresh.write_bytes(b"x")
    os.utime(stale, (time.time() - 7200,) * 2)
    tiny = {**SMALL, "width": 8, "height": 6}
    paths = []
    for seed in range(3):
        make_procedural_scene(**{**tiny, "seed": seed}, disk_cache=True)
        paths.append(P.procedural_cache_path(next(reversed(no_memo))))
        os.utime(paths[-1], (time.time() - 100 + seed,) * 2)  # distinct ages, oldest first
    assert not paths[0].exists() and paths[1].exists() and paths[2].exists()
    assert not stale.exists() and fresh.exists()  # a write killed an hour ago; one that may be running
    no_memo.clear()
    make_procedural_scene(**{**tiny, "seed": 1}, disk_cache=True)  # read: marked as used
    make_procedural_scene(**{**tiny, "seed": 0}, disk_cache=True)  # rendered, written: seed 2's file goes
    assert paths[0].exists() and paths[1].exists() and not paths[2].exists()


@pytest.mark.parametrize("damage", ["garbage", "truncated", "other_key", "other_shape", "other_type"])
def test_a_bad_cache_file_is_rendered_again(no_memo, tmp_path, monkeypatch, damage):
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path))
    fresh = make_procedural_scene(**SMALL, disk_cache=True)
    settings = next(iter(no_memo))
    path = P.procedural_cache_path(settings)
    good = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not an npz")
    elif damage == "truncated":
        path.write_bytes(good[: len(good) // 2])
    else:
        with np.load(path) as z:
            ims, deps, key = z["images"], z["depths"], str(z["key"])
        if damage == "other_key":
            key = "0" * 64
        elif damage == "other_type":
            ims = ims.astype(np.float64)
        else:
            ims, deps = ims[:, :-1], deps[:, :-1]
        with open(path, "wb") as f:
            np.savez(f, key=np.array(key), images=ims, depths=deps)
    no_memo.clear()
    _same_scene(fresh, make_procedural_scene(**SMALL, disk_cache=True))
    assert path.read_bytes() == good  # rewritten


def test_a_refused_cache_write_is_ignored(no_memo, tmp_path, monkeypatch):
    """A cache folder that cannot be made (a file in its place), or a write the disk refuses
    half way: the scene still comes, and no file (or temporary file) is left behind."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("REINGS_CACHE_DIR", str(blocker))
    fresh = make_procedural_scene(**SMALL, disk_cache=True)
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path / "full"))
    no_memo.clear()

    def full(f, **arrays):
        f.write(b"x" * 100)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", full)
    _same_scene(fresh, make_procedural_scene(**SMALL, disk_cache=True))
    assert list((tmp_path / "full" / "procedural").iterdir()) == []


def test_the_cache_key_names_the_settings_and_the_bits_sources(monkeypatch):
    base = (3, 40, 30, 0, 1, 30.0, (0, 1, 2))
    others = [(3, 40, 30, s, 1, 30.0, (0, 1, 2)) for s in (1, 2)] + [
        (3, 40, 30, 0, 2, 30.0, (0, 1, 2)), (3, 40, 30, 0, 1, 31.0, (0, 1, 2)), (3, 40, 30, 0, 1, 30.0, (2, 1, 0)),
        (3, 41, 30, 0, 1, 30.0, (0, 1, 2)), (4, 40, 30, 0, 1, 30.0, (0, 1, 2))]
    keys = {P.procedural_cache_key(k) for k in [base, *others]}
    assert len(keys) == 1 + len(others)
    k0 = P.procedural_cache_key(base)
    monkeypatch.setattr(P, "_numpy_fingerprint", lambda: "another numpy")
    assert P.procedural_cache_key(base) != k0
    monkeypatch.undo()
    import platform
    monkeypatch.setattr(platform, "machine", lambda: "another machine")
    assert P.procedural_cache_key(base) != k0
    fp = P._numpy_fingerprint()
    assert np.__version__ in fp and "|" in fp


def test_the_cache_key_reads_the_sources(monkeypatch, tmp_path):
    """The key hashes procedural.py and types.py (the cameras): an edit of either is another key."""
    from reings import types

    base = (3, 40, 30, 0, 1, 30.0, (0, 1, 2))
    k0 = P.procedural_cache_key(base)
    for mod, name in ((P, "procedural.py"), (types, "types.py")):
        edited = tmp_path / name
        edited.write_bytes(open(mod.__file__, "rb").read() + b"\n# an edit\n")
        with monkeypatch.context() as m:
            m.setattr(mod, "__file__", str(edited))
            assert P.procedural_cache_key(base) != k0, name


def test_a_run_reads_the_scene_through_the_disk_cache(no_memo, tmp_path, monkeypatch):
    from reings.pipeline import load_run_scene

    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path))
    calls = []
    real = P.make_procedural_scene
    monkeypatch.setattr(P, "make_procedural_scene", lambda **k: calls.append(k) or real(**{**k, **SMALL}))
    scene = load_run_scene(None)
    assert calls == [{"disk_cache": True}] and len(scene) == 3
    assert len(list((tmp_path / "procedural").iterdir())) == 1
    load_run_scene("procedural", "procedural")
    assert calls[1:] == [{"disk_cache": True}]
    # a folder named "procedural" read as another format is that format's (a missing folder here)
    from reings.data.loader import SceneError

    for data, dataset in (("procedural", "llff"), (None, "colmap")):
        with pytest.raises(SceneError):
            load_run_scene(data, dataset)
    assert len(calls) == 2


def test_views_renders_only_those_and_the_same_bits(no_memo):
    full = make_procedural_scene(n_views=6, width=24, height=18, seed=1, supersample=2)
    no_memo.clear()
    part = make_procedural_scene(n_views=6, width=24, height=18, seed=1, supersample=2, views=(4, 1))
    assert part.names == ["view004.png", "view001.png"] and len(part) == 2
    for k, v in enumerate((4, 1)):
        np.testing.assert_array_equal(part.images[k], full.images[v])
        np.testing.assert_array_equal(part.depths[k], full.depths[v])
        np.testing.assert_array_equal(part.cameras[k].viewmat, full.cameras[v].viewmat)
        np.testing.assert_array_equal(part.bounds[k], full.bounds[v])
    assert part.meta["views"] == [4, 1] and part.meta["n_views"] == 6 and "views" not in full.meta
    for bad in ((), (6,), (-1,), (1, 1)):
        with pytest.raises(ValueError, match=r"views .* must be distinct indices in \[0, 6\)"):
            make_procedural_scene(n_views=6, width=24, height=18, views=bad)
    for bad in ((1.5,), "12", (None,)):
        with pytest.raises(ValueError, match=r"views .* must be integer indices in \[0, 6\)"):
            make_procedural_scene(n_views=6, width=24, height=18, views=bad)
    with pytest.raises(TypeError):
        make_procedural_scene(n_views=6, width=24, height=18, seed=1.5)
