"""Scene extent from the training views only (docs/method.md §1.3, EHPS's box V), without leakage.

`sfm_extent(train_scene)`:
1. SfM with known poses on the k training images only (COLMAP `point_triangulator` flow as FSGS
   `tools/colmap_llff.py`, through pycolmap in `colmap.triangulate_known_poses`): SIFT on each
   image, exhaustive matching with geometric verification, triangulation with the given
   intrinsics and poses held fixed. The images are written to a temporary folder as 8-bit PNG.
2. A robust axis-aligned box of those points: per axis, lo = the k-th smallest coordinate and
   hi = the k-th largest (order statistics; k = 20 for forward-facing scenes as DNGaussian's
   LLFF `lo`, k = 100 for DTU as DNGaussian's DTU box; k shrinks to a tenth of the point count
   when few points exist). The untrimmed min/max come along (`lo_all`, `hi_all`) so that
   DNGaussian's exact rule (lo = 20th smallest, side = max - min) can be rebuilt.
3. Fallback when fewer than `min_points` triangulate: the intersection of the training frusta,
   each cut at its own view's near/far bounds (`Scene.bounds` of the training views only), as an
   axis-aligned box (`frusta_extent`).

Nothing here reads a file of the dataset: it only sees the `Scene` it is given, which should be
`scene.subset(train)`.

Cache: the result is stored as one .npz under `$REINGS_CACHE_DIR/sfm` (else
`$XDG_CACHE_HOME/reings/sfm`, else `~/.cache/reings/sfm`), named by a sha256 of the training
images' pixels (float32 as loaded), their cameras (K, viewmat, size), the near/far bounds, the
scene kind and every setting that changes the result (`sfm_cache_key`). Files are written
atomically (temp file + rename); an unreadable or mismatching file is recomputed. The cache lets a
machine without pycolmap reuse boxes computed elsewhere: copy the cache folder over (`reings eval
--prepare-only` fills it for a whole dataset). Without pycolmap and without a cached result the
frusta fallback is used, with a warning (`SfmExtent.note` says so).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cachekey import hash_image, hash_rounded
from .types import Scene, SceneError

TRIM_OF_KIND = {"dtu": 100}  # order statistic per kind; default 20 (LLFF)
DEFAULT_TRIM = 20
DEFAULT_MIN_POINTS = 50  # below this the box of a handful of points is noise: use the frusta
SFM_CACHE_VERSION = 2  # 2: machine-independent key (cachekey.py)


@dataclass
class SfmExtent:
    """An axis-aligned box [lo, hi] (world units) and the points it came from."""

    lo: np.ndarray  # [3]
    hi: np.ndarray  # [3]
    method: str  # "sfm" (triangulated points) or "frusta" (fallback)
    points: np.ndarray  # [P, 3] float64 (empty for "frusta")
    colors: np.ndarray  # [P, 3] float32 in [0, 1]
    lo_all: np.ndarray | None = None  # [3] untrimmed min (sfm only)
    hi_all: np.ndarray | None = None  # [3] untrimmed max (sfm only)
    trim: int = 0
    num_matched_pairs: int = 0
    num_sfm_points: int = 0  # points triangulated, even when the fallback was used
    note: str = ""  # why a fallback was used when it was not for lack of points (e.g. no pycolmap)
    cached: bool = False  # True when this result was read from the on-disk cache

    @property
    def n_points(self) -> int:
        return int(len(self.points))

    @property
    def size(self) -> np.ndarray:
        return self.hi - self.lo

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (self.lo + self.hi)


def robust_aabb(points: np.ndarray, trim: int = DEFAULT_TRIM) -> tuple[np.ndarray, np.ndarray, int]:
    """(lo, hi, k): per-axis k-th smallest and k-th largest coordinate (1-based k, so k = 1 is min/max).

    k = min(trim, max(1, n // 10)) so that a small cloud keeps 80 % of its spread per axis.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(p)
    if n == 0:
        raise ValueError("robust_aabb: no points")
    k = int(min(max(1, trim), max(1, n // 10)))
    s = np.sort(p, axis=0)
    return s[k - 1].copy(), s[n - k].copy(), k


def _frustum_samples(cam, near: float, far: float, n_uv: int, n_z: int) -> np.ndarray:
    """World points on a regular grid filling the frustum of `cam` between depths near and far."""
    u = np.linspace(0, cam.width, n_uv)
    v = np.linspace(0, cam.height, n_uv)
    z = np.linspace(near, far, n_z)
    uu, vv, zz = np.meshgrid(u, v, z, indexing="ij")
    pix = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1)
    Xc = (pix @ np.linalg.inv(cam.K).T) * zz.ravel()[:, None]  # camera coords, z = depth
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    return (Xc - t) @ R  # world = R^T (Xc - t)


def _inside(cam, near: float, far: float, X: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    Xc = X @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (Xc @ cam.K.T)[:, :2] / z[:, None]
    return ((z >= near * (1 - tol)) & (z <= far * (1 + tol)) & (uv[:, 0] >= -tol) & (uv[:, 0] <= cam.width + tol)
            & (uv[:, 1] >= -tol) & (uv[:, 1] <= cam.height + tol))


def frusta_extent(cameras, bounds, n_uv: int = 24, n_z: int = 48) -> tuple[np.ndarray, np.ndarray, str]:
    """(lo, hi, how) of the intersection of the cameras' frusta cut at their (near, far) bounds.

    Sampled: a grid in each frustum, kept where it lies inside every frustum; how = "intersection".
    If the frusta do not overlap (how = "union"), the box of all the frusta is returned instead.
    """
    bounds = np.asarray(bounds, dtype=np.float64).reshape(-1, 2)
    if len(bounds) != len(cameras):
        raise ValueError(f"frusta_extent: {len(bounds)} bounds for {len(cameras)} cameras")
    if not (np.all(np.isfinite(bounds)) and np.all(bounds[:, 0] > 0) and np.all(bounds[:, 1] > bounds[:, 0])):
        raise ValueError(f"frusta_extent: bad near/far bounds {bounds.tolist()}")
    kept, every = [], []
    for cam, (nr, fr) in zip(cameras, bounds):
        X = _frustum_samples(cam, nr, fr, n_uv, n_z)
        every.append(X)
        m = np.ones(len(X), dtype=bool)
        for cam2, (nr2, fr2) in zip(cameras, bounds):
            if cam2 is not cam:
                m &= _inside(cam2, nr2, fr2, X)
        kept.append(X[m])
    K = np.concatenate(kept)
    if len(K) >= 8:
        return K.min(0), K.max(0), "intersection"
    A = np.concatenate(every)
    return A.min(0), A.max(0), "union"


# {{{ on-disk cache

def sfm_cache_dir() -> Path:
    """$REINGS_CACHE_DIR/sfm, else $XDG_CACHE_HOME/reings/sfm, else ~/.cache/reings/sfm."""
    from ..io.files import cache_dir

    return cache_dir("sfm")


def sfm_cache_key(train_scene: Scene, settings: dict) -> str:
    """sha256 of what determines `sfm_extent`'s result: pixels, cameras, bounds, kind, settings."""
    h = hashlib.sha256()
    h.update(f"reings-sfm-v{SFM_CACHE_VERSION}".encode())
    h.update(json.dumps({"kind": train_scene.kind, **settings}, sort_keys=True).encode())
    for im, cam in zip(train_scene.images, train_scene.cameras):
        hash_image(h, im)  # machine-independent forms (reings/data/cachekey.py)
        hash_rounded(h, cam.K, 4)
        hash_rounded(h, cam.viewmat, 6)
        h.update(f"{int(cam.width)}x{int(cam.height)}".encode())
    if train_scene.bounds is not None:
        hash_rounded(h, train_scene.bounds, 6)
    return h.hexdigest()


_ARRAYS = ("lo", "hi", "points", "colors", "lo_all", "hi_all")
_SCALARS = ("method", "trim", "num_matched_pairs", "num_sfm_points", "note")


def _cache_path(cache_dir: Path, key: str) -> Path:
    return Path(cache_dir) / f"sfm-{key[:40]}.npz"


def load_cached_extent(key: str, cache_dir=None) -> SfmExtent | None:
    """The cached SfmExtent of `key`, or None (missing, unreadable or another key)."""
    p = _cache_path(Path(cache_dir) if cache_dir is not None else sfm_cache_dir(), key)
    if not p.is_file():
        return None
    try:
        with np.load(p, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("key") != key or meta.get("version") != SFM_CACHE_VERSION:
                return None
            arrs = {k: (z[k].copy() if k in z.files else None) for k in _ARRAYS}
        ext = SfmExtent(arrs["lo"].astype(np.float64), arrs["hi"].astype(np.float64), str(meta["method"]),
                        arrs["points"].astype(np.float64).reshape(-1, 3), arrs["colors"].astype(np.float32).reshape(-1, 3),
                        None if arrs["lo_all"] is None else arrs["lo_all"].astype(np.float64),
                        None if arrs["hi_all"] is None else arrs["hi_all"].astype(np.float64),
                        int(meta["trim"]), int(meta["num_matched_pairs"]), int(meta["num_sfm_points"]),
                        str(meta.get("note", "")), cached=True)
        if ext.lo.shape != (3,) or ext.hi.shape != (3,) or not (np.all(np.isfinite(ext.lo)) and np.all(np.isfinite(ext.hi))):
            return None
        return ext
    except Exception:  # corrupt, truncated or foreign file: recompute
        return None


def store_cached_extent(key: str, ext: SfmExtent, cache_dir=None) -> Path:
    """Write `ext` under `key` atomically (temp file in the same folder + rename)."""
    d = Path(cache_dir) if cache_dir is not None else sfm_cache_dir()
    d.mkdir(parents=True, exist_ok=True)
    meta = {"key": key, "version": SFM_CACHE_VERSION, **{k: getattr(ext, k) for k in _SCALARS}}
    meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in meta.items()}
    arrs = {k: np.asarray(getattr(ext, k)) for k in _ARRAYS if getattr(ext, k) is not None}
    from ..io.files import atomic_write

    with atomic_write(_cache_path(d, key), binary=True) as f:
        np.savez(f, meta=np.array(json.dumps(meta)), **arrs)
    return _cache_path(d, key)


class _Skip(Exception):
    pass


def _have_pycolmap() -> bool:
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        return False
    return True
# }}}


def frusta_only_extent(train_scene: Scene) -> SfmExtent:
    """The training-frusta box without running SfM (`reings run --extent frusta`): what
    `sfm_extent` falls back to, asked for directly (e.g. to match a run made on a machine without
    pycolmap). Needs the views' near/far bounds."""
    if train_scene.bounds is None:
        raise SceneError("frusta extent: the training views have no near/far bounds")
    lo, hi, _ = frusta_extent(train_scene.cameras, train_scene.bounds)
    return SfmExtent(lo, hi, "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32), note="requested")


def sfm_extent(train_scene: Scene, min_points: int = DEFAULT_MIN_POINTS, trim: int | None = None,
               fallback: bool = True, max_features: int = 8192, max_reproj_error: float = 4.0,
               min_tri_angle: float = 1.5, num_threads: int = 2, work_dir: str | None = None,
               peak_threshold: float | None = None, guided_matching: bool = True, cache: bool = True,
               cache_dir=None) -> SfmExtent:
    """Triangulate the training views with their known poses and return a robust box (see module doc).

    Args:
        train_scene: the training views only (`scene.subset(train)`); 2 or more views.
        min_points: below this many triangulated points, use the frusta fallback.
        trim: order statistic for the box (default 20, or 100 for DTU).
        fallback: if False, raise `SceneError` instead of falling back.
        work_dir: keep COLMAP's database and model there (default: a temporary folder, removed).
        peak_threshold: SIFT peak threshold (COLMAP default 0.0067; lower gives more features).
        guided_matching: re-match guided by the verified two-view geometry (more inliers).
        cache: read/write the on-disk cache (module doc); a given `work_dir` always recomputes
            (the caller wants COLMAP's files) and then stores the result.
        cache_dir: cache folder (default `sfm_cache_dir()`).
    """
    if len(train_scene) < 2:
        raise SceneError("sfm_extent: needs at least 2 training views")
    trim = TRIM_OF_KIND.get(train_scene.kind, DEFAULT_TRIM) if trim is None else int(trim)
    settings = {"min_points": int(min_points), "trim": trim, "fallback": bool(fallback),
                "max_features": int(max_features), "max_reproj_error": float(max_reproj_error),
                "min_tri_angle": float(min_tri_angle), "peak_threshold": peak_threshold,
                "guided_matching": bool(guided_matching)}
    key = sfm_cache_key(train_scene, settings) if cache else None
    if cache and work_dir is None:
        got = load_cached_extent(key, cache_dir)
        if got is not None:
            return got
    have = _have_pycolmap()
    if not have:
        if not fallback:
            raise SceneError("sfm_extent: pycolmap is not installed and no cached SfM result matches these "
                             f"training views (key {key and key[:16]}, cache {cache_dir or sfm_cache_dir()})")
        warnings.warn("sfm_extent: pycolmap is not installed and no cached result matches these training views "
                      f"(cache {cache_dir or sfm_cache_dir()}): using the frusta fallback. Install pycolmap, or "
                      "copy the sfm cache from a machine that computed it.", RuntimeWarning, stacklevel=2)
    ext = _sfm_extent_uncached(train_scene, min_points, trim, fallback, max_features, max_reproj_error,
                               min_tri_angle, num_threads, work_dir, peak_threshold, guided_matching,
                               run_sfm=have)
    if not have:
        ext.note = "no pycolmap"
    elif cache:  # a machine without pycolmap must not poison the cache with its fallback
        try:
            store_cached_extent(key, ext, cache_dir)
        except OSError as e:  # read-only cache: the result is still good
            warnings.warn(f"sfm_extent: could not write the cache ({e})", RuntimeWarning, stacklevel=2)
    return ext


def _sfm_extent_uncached(train_scene, min_points, trim, fallback, max_features, max_reproj_error,
                         min_tri_angle, num_threads, work_dir, peak_threshold, guided_matching,
                         run_sfm: bool = True) -> SfmExtent:
    from . import images as imgs
    from .colmap import triangulate_known_poses

    res = {"xyz": np.zeros((0, 3)), "rgb": np.zeros((0, 3), np.float32), "num_matched_pairs": 0}
    tmp = (work_dir or tempfile.mkdtemp(prefix="reings_sfm_")) if run_sfm else None
    try:
        if not run_sfm:
            raise _Skip
        img_dir = os.path.join(tmp, "images")
        os.makedirs(img_dir, exist_ok=True)
        names = []
        for i, (im, n) in enumerate(zip(train_scene.images, train_scene.names)):
            base = os.path.splitext(os.path.basename(n))[0]
            name = f"{i:03d}_{base}.png"
            imgs.write_png(os.path.join(img_dir, name), im)
            names.append(name)
        try:
            res = triangulate_known_poses(img_dir, names, list(train_scene.cameras), tmp,
                                          max_features=max_features, max_reproj_error=max_reproj_error,
                                          min_tri_angle=min_tri_angle, num_threads=num_threads,
                                          peak_threshold=peak_threshold, guided_matching=guided_matching)
        except SceneError:
            if not fallback:
                raise
    except _Skip:
        pass
    finally:
        if work_dir is None and tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    xyz = res["xyz"]
    ok = np.all(np.isfinite(xyz), axis=1)
    xyz, rgb = xyz[ok], res["rgb"][ok]
    n = len(xyz)
    if n >= max(1, min_points):
        lo, hi, k = robust_aabb(xyz, trim)
        return SfmExtent(lo, hi, "sfm", xyz, rgb, xyz.min(0), xyz.max(0), k,
                         res["num_matched_pairs"], n)
    if not fallback:
        raise SceneError(f"sfm_extent: only {n} points triangulated from {len(train_scene)} views (< {min_points})")
    if train_scene.bounds is None:
        raise SceneError(f"sfm_extent: only {n} points triangulated and the training views have no near/far "
                         "bounds for the frusta fallback")
    lo, hi, _ = frusta_extent(train_scene.cameras, train_scene.bounds)
    return SfmExtent(lo, hi, "frusta", np.zeros((0, 3)), np.zeros((0, 3), np.float32), None, None, 0,
                     res["num_matched_pairs"], n)
