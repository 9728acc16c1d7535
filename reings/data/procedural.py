"""A built-in scene with exact depth, ray traced with numpy (no splatting code involved).

`make_procedural_scene()` needs no files: it lays out a textured ground plane, a textured back
wall, boxes (rotated about the vertical axis) and spheres, lit by one directional light with hard
shadows plus ambient (Lambertian), and renders them from views on a forward-facing arc, like an
LLFF capture. Every pixel hits the ground or the wall, so each view has an exact, finite
per-pixel depth (camera-space z of the pixel-centre ray). Colours are averaged over
`supersample`^2 sub-pixel rays. Everything is a deterministic function of `seed`.

World frame: y up, ground at y = 0, cameras at z ~ -4.5 looking towards +z; cameras are
`reings.Camera` (OpenCV axes, pixel centres at +0.5) like every loader's.
"""
from __future__ import annotations

import operator
import os
from typing import NamedTuple

import numpy as np

from ..log import logger
from ..types import Camera
from .types import Scene

_WALL_Z = 5.0  # back wall plane z = _WALL_Z; every camera ray has d_z > 0, so each one hits it
_LIGHT = np.array([-0.45, 0.8, -0.4]) / np.linalg.norm([-0.45, 0.8, -0.4])  # towards the light
_AMBIENT = 0.3


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-camera 4x4 (OpenCV axes: x right, y down, z forward) for a camera at `eye`."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)  # right-handed, y-up world: forward x up = camera right
    r /= np.linalg.norm(r)
    d = np.cross(f, r)  # camera down
    V = np.eye(4)
    V[:3, :3] = np.stack([r, d, f])
    V[:3, 3] = -V[:3, :3] @ eye
    return V


class _Noise:
    """Smooth value noise on a periodic lattice (bilinear with smoothstep), values in [0, 1]."""

    def __init__(self, rng: np.random.Generator, n: int = 64):
        self.n = n
        self.grid = rng.random((n, n))

    def __call__(self, u: np.ndarray, v: np.ndarray, octaves: int = 3) -> np.ndarray:
        out = np.zeros_like(u)
        amp, tot, freq = 1.0, 0.0, 1.0
        for _ in range(octaves):
            x, y = u * freq, v * freq
            x0, y0 = np.floor(x), np.floor(y)
            fx, fy = x - x0, y - y0
            fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
            i0, j0 = x0.astype(np.int64) % self.n, y0.astype(np.int64) % self.n
            i1, j1 = (i0 + 1) % self.n, (j0 + 1) % self.n
            g = self.grid
            a = g[i0, j0] * (1 - fx) + g[i1, j0] * fx
            b = g[i0, j1] * (1 - fx) + g[i1, j1] * fx
            out += amp * (a * (1 - fy) + b * fy)
            tot += amp
            amp *= 0.5
            freq *= 2.0
        return out / tot


def _layout(rng: np.random.Generator) -> dict:
    """Object placement and colours (positions jittered by the seed)."""
    j = lambda s: rng.uniform(-s, s)  # noqa: E731
    spheres = [
        (np.array([-1.1 + j(0.15), 0.55, 0.4 + j(0.2)]), 0.55, rng.uniform(0.3, 0.9, 3)),
        (np.array([1.2 + j(0.15), 0.4, -0.5 + j(0.2)]), 0.4, rng.uniform(0.3, 0.9, 3)),
        (np.array([0.3 + j(0.1), 0.3, -1.3 + j(0.1)]), 0.3, rng.uniform(0.3, 0.9, 3)),
    ]
    boxes = [  # centre, half sizes, yaw, colour
        (np.array([0.2 + j(0.15), 0.6, 1.4 + j(0.2)]), np.array([0.6, 0.6, 0.5]), rng.uniform(0.2, 0.7),
         rng.uniform(0.3, 0.9, 3)),
        (np.array([-0.3 + j(0.1), 0.25, -0.6 + j(0.1)]), np.array([0.3, 0.25, 0.3]), rng.uniform(-0.6, 0.0),
         rng.uniform(0.3, 0.9, 3)),
    ]
    for s in spheres:  # spheres rest on the ground
        s[0][1] = s[1]
    return {"spheres": spheres, "boxes": boxes}


def _hit_sphere(o, d, c, r):
    """Smallest t > eps of |o + t d - c| = r per ray, inf where missed. o [3] or [R, 3], d [R, 3]."""
    oc = o - c
    a = np.einsum("ij,ij->i", d, d)
    b = 2 * np.einsum("ij,ij->i", d, oc if oc.ndim == 2 else np.broadcast_to(oc, d.shape))
    cc = (np.einsum("ij,ij->i", oc, oc) if oc.ndim == 2 else float(oc @ oc)) - r * r
    disc = b * b - 4 * a * cc
    ok = disc >= 0
    sq = np.sqrt(np.where(ok, disc, 0))
    t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
    t = np.where(t0 > 1e-6, t0, np.where(t1 > 1e-6, t1, np.inf))
    return np.where(ok, t, np.inf)


def _box_frame(yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])  # world -> box local rotation


def _hit_box(o, d, centre, half, yaw):
    """(t, local hit normal axis index and sign) for a box rotated by `yaw` about y."""
    Rb = _box_frame(yaw)
    ol = (o - centre) @ Rb.T
    dl = d @ Rb.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(dl) < 1e-12, 1e-12, dl)
        t1 = (-half - ol) * inv
        t2 = (half - ol) * inv
    tmin = np.minimum(t1, t2)
    tmax = np.maximum(t1, t2)
    tn = tmin.max(axis=1)
    tf = tmax.min(axis=1)
    hit = (tn <= tf) & (tf > 1e-6)
    t = np.where(hit, np.where(tn > 1e-6, tn, tf), np.inf)
    axis = tmin.argmax(axis=1)
    return t, axis


def _trace(o, d, L, noise, depth_only: bool = False):
    """(rgb [R, 3] or None, t [R]) for rays o + t d (o [3], d [R, 3] with d's camera-z component = 1)."""
    R = d.shape[0]
    best = np.full(R, np.inf)
    kind = np.full(R, -1)  # 0 ground, 1 wall, 2+i sphere i, 10+i box i
    # ground y = 0 (from above only)
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(d[:, 1] < -1e-12, -o[1] / d[:, 1], np.inf)
        tw = np.where(d[:, 2] > 1e-12, (_WALL_Z - o[2]) / d[:, 2], np.inf)
    for k, t in ((0, tg), (1, tw)):
        m = (t > 1e-6) & (t < best)
        best[m], kind[m] = t[m], k
    for i, (c, r, _) in enumerate(L["spheres"]):
        t = _hit_sphere(o, d, c, r)
        m = t < best
        best[m], kind[m] = t[m], 2 + i
    box_axis = np.zeros(R, dtype=np.int64)
    for i, (c, h, yaw, _) in enumerate(L["boxes"]):
        t, ax = _hit_box(o, d, c, h, yaw)
        m = t < best
        best[m], kind[m], box_axis[m] = t[m], 10 + i, ax[m]
    if depth_only:
        return None, best
    p = o + best[:, None] * d  # [R, 3]
    albedo = np.zeros((R, 3))
    normal = np.zeros((R, 3))
    m = kind == 0  # ground: checker mixed with noise
    if m.any():
        x, z = p[m, 0], p[m, 2]
        chk = ((np.floor(x * 2) + np.floor(z * 2)) % 2)[:, None]
        n = noise(x * 3 + 17, z * 3 + 5)[:, None]
        albedo[m] = (0.35 + 0.35 * chk) * np.array([0.9, 0.85, 0.7]) * (0.6 + 0.8 * n)
        normal[m] = (0, 1, 0)
    m = kind == 1  # wall: noisy bricks
    if m.any():
        x, y = p[m, 0], p[m, 1]
        row = np.floor(y * 3)
        bx = (x * 1.5 + 0.5 * (row % 2)) % 1.0
        mortar = ((bx < 0.06) | ((y * 3) % 1.0 < 0.08))[:, None]
        n = noise(x * 4 + 31, y * 4 + 9)[:, None]
        brick = np.array([0.7, 0.35, 0.25]) * (0.6 + 0.7 * n)
        albedo[m] = np.where(mortar, np.array([0.8, 0.8, 0.75]), brick)
        normal[m] = (0, 0, -1)
    for i, (c, r, col) in enumerate(L["spheres"]):
        m = kind == 2 + i
        if m.any():
            q = (p[m] - c) / r
            theta = np.arctan2(q[:, 2], q[:, 0])
            phi = np.arccos(np.clip(q[:, 1], -1, 1))
            stripes = (np.floor(theta * 6 / np.pi) + np.floor(phi * 5 / np.pi)) % 2
            n = noise(theta * 4 + 50 + i * 7, phi * 4)
            albedo[m] = col * (0.55 + 0.35 * stripes + 0.3 * n)[:, None]
            normal[m] = q
    for i, (c, h, yaw, col) in enumerate(L["boxes"]):
        m = kind == 10 + i
        if m.any():
            Rb = _box_frame(yaw)
            ql = (p[m] - c) @ Rb.T
            ax = box_axis[m]
            nl = np.zeros_like(ql)
            nl[np.arange(len(ax)), ax] = np.sign(ql[np.arange(len(ax)), ax])
            normal[m] = nl @ Rb
            # face coordinates: the two other local axes
            uv = np.where(ax[:, None] == 0, ql[:, [1, 2]], np.where(ax[:, None] == 1, ql[:, [0, 2]], ql[:, [0, 1]]))
            chk = (np.floor(uv[:, 0] * 5) + np.floor(uv[:, 1] * 5)) % 2
            n = noise(uv[:, 0] * 6 + 70 + i * 11 + ax * 3, uv[:, 1] * 6)
            albedo[m] = col * (0.5 + 0.3 * chk + 0.4 * n)[:, None]
    # shading: Lambert + hard shadows from the spheres and boxes
    ndl = np.clip(normal @ _LIGHT, 0, None)
    lit = ndl > 0
    if lit.any():
        ps = p[lit] + 1e-4 * normal[lit]
        dl = np.broadcast_to(_LIGHT, ps.shape)
        occ = np.zeros(len(ps), dtype=bool)
        for c, r, _ in L["spheres"]:
            occ |= np.isfinite(_hit_sphere(ps, dl, c, r))
        for c, h, yaw, _ in L["boxes"]:
            occ |= np.isfinite(_hit_box(ps, dl, c, h, yaw)[0])
        ndl[np.flatnonzero(lit)[occ]] = 0.0
    rgb = albedo * (_AMBIENT + (1 - _AMBIENT) * ndl)[:, None]
    return np.clip(rgb, 0, 1), best


def procedural_cameras(n_views: int = 24, width: int = 200, height: int = 150, arc_degrees: float = 30.0,
                       radius: float = 4.2, fov_x_degrees: float = 60.0) -> list[Camera]:
    """Cameras on a forward-facing arc about the scene centre, heights on a gentle wave (LLFF-like)."""
    fx = 0.5 * width / np.tan(np.radians(fov_x_degrees) / 2)
    K = np.array([[fx, 0, width / 2.0], [0, fx, height / 2.0], [0, 0, 1]])
    target = np.array([0.0, 0.45, 0.4])
    cams = []
    angles = np.radians(np.linspace(-arc_degrees / 2, arc_degrees / 2, n_views)) if n_views > 1 else np.zeros(1)
    for k, a in enumerate(angles):
        y = 1.6 + 0.35 * np.sin(2.0 * np.pi * k / max(n_views, 1) * 2)
        eye = np.array([radius * np.sin(a), y, 0.4 - radius * np.cos(a)])
        cams.append(Camera(K.copy(), look_at(eye, target), width, height))
    return cams


def render_view(cam: Camera, layout: dict, noise: _Noise, supersample: int = 2):
    """(rgb [H, W, 3] float32, depth [H, W] float32 camera-space z) of one view."""
    W, H, ss = cam.width, cam.height, max(1, int(supersample))
    Rwc = cam.viewmat[:3, :3].T  # camera -> world rotation
    o = cam.center
    Kinv = np.linalg.inv(cam.K)
    # centre rays: depth; sub-pixel rays: colour (offsets (s + 0.5) / ss within the pixel)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dc = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1) @ Kinv.T  # [HW, 3], z = 1
    _, t = _trace(o, dc @ Rwc.T, layout, noise, depth_only=True)
    depth = t.reshape(H, W)  # camera z = t, since the direction's camera z is 1
    rgb = np.zeros((H * W, 3))
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for ox in offs:
        for oy in offs:
            ds = np.stack([u.ravel() + ox, v.ravel() + oy, np.ones(u.size)], 1) @ Kinv.T
            c, _ = _trace(o, ds @ Rwc.T, layout, noise)
            rgb += c
    rgb /= ss * ss
    return rgb.reshape(H, W, 3).astype(np.float32), depth.astype(np.float32)


def make_procedural_scene(n_views: int = 24, width: int = 200, height: int = 150, seed: int = 0,
                          supersample: int = 2, arc_degrees: float = 30.0, disk_cache: bool = False,
                          views=None) -> Scene:
    """The built-in scene: `n_views` images with exact depths (`Scene.depths`) and cameras.

    Per-view bounds are the view's own depth range (min, max). Names are view000.png, ...
    `views`: only these of the arc's `n_views` cameras (distinct integer indices, in this order;
    names keep the arc's index, `meta["views"]` lists them), the others not rendered. A split of
    such a scene (`few_shot_split`) counts its positions, not the arc's indices.

    The ray tracing takes seconds (6-12 s for the default on one core of the machines measured),
    so the images and depths of the last few settings are kept in the process (every call returns
    its own copies), and with `disk_cache` (what `reings run` / `eval` load:
    `pipeline.load_run_scene`) also in one .npz per setting under `cache_dir("procedural")`
    ($REINGS_CACHE_DIR/procedural, else the user cache folder), named by a hash of the settings
    and of what the bits depend on (`procedural_cache_key`), written atomically, the 8 most
    recently used kept; an unreadable or mismatching file is rendered again, a refused write ignored.
    """
    n_views, width, height, seed, supersample = (operator.index(v) for v in (n_views, width, height, seed,
                                                                              supersample))
    idx = tuple(range(n_views)) if views is None else _view_indices(views, n_views)
    settings = _Settings(n_views, width, height, seed, max(1, supersample), float(arc_degrees), idx)
    arc = procedural_cameras(n_views, width, height, arc_degrees)
    cams = [arc[v] for v in idx]
    rendered = _MEMO.get(settings)
    key = procedural_cache_key(settings) if rendered is None and disk_cache else None
    if key is not None:
        rendered = _load_cached(settings, key)
    if rendered is None:
        rendered = _render_views(settings, cams)
        if key is not None:
            _store_cached(key, rendered)
    _MEMO.pop(settings, None)
    _MEMO[settings] = rendered  # the most recently used last
    while len(_MEMO) > _MEMO_SIZE:
        _MEMO.pop(next(iter(_MEMO)))
    ims, deps = [im.copy() for im in rendered[0]], [d.copy() for d in rendered[1]]
    bounds = np.array([[d.min(), d.max()] for d in deps], dtype=np.float64)
    names = [f"view{v:03d}.png" for v in idx]
    meta = {"seed": seed, "supersample": supersample}
    if views is not None:
        meta.update(n_views=n_views, views=list(idx))
    return Scene(ims, cams, names, kind="procedural", bounds=bounds, depths=deps, source="procedural", meta=meta)


def _view_indices(views, n_views: int) -> tuple:
    """`views` as a tuple of distinct ints in [0, n_views), or ValueError naming the problem."""
    try:
        idx = tuple(operator.index(v) for v in views)
    except TypeError:
        raise ValueError(f"make_procedural_scene: views {views!r} must be integer indices in [0, {n_views})") from None
    if not idx or not all(0 <= v < n_views for v in idx) or len(set(idx)) != len(idx):
        raise ValueError(f"make_procedural_scene: views {views!r} must be distinct indices in [0, {n_views})")
    return idx


# {{{ the scene's views, rendered or cached

class _Settings(NamedTuple):
    """What a scene's views depend on (the memo's key; hashed into the disk cache's)."""
    n_views: int
    width: int
    height: int
    seed: int
    supersample: int
    arc_degrees: float
    views: tuple


_MEMO: dict = {}  # settings -> (images, depths): read-only arrays, the most recently used last
_MEMO_SIZE = 4
_DISK_KEEP = 8  # cache files kept in the folder, the most recently used
PROCEDURAL_CACHE_VERSION = 1


def _render_views(settings: tuple, cams) -> tuple:
    """(images, depths) of `make_procedural_scene`'s settings, ray traced; arrays read-only."""
    rng = np.random.default_rng(settings.seed)
    layout = _layout(rng)
    noise = _Noise(rng)
    ims, deps = [], []
    for cam in cams:
        rgb, dep = render_view(cam, layout, noise, settings.supersample)
        rgb.flags.writeable = dep.flags.writeable = False
        ims.append(rgb)
        deps.append(dep)
    return tuple(ims), tuple(deps)


def procedural_cache_key(settings: tuple) -> str:
    """sha256 of the settings and of what the images' bits depend on besides them: the source of
    this module and of reings/types.py (the cameras), numpy's version and BLAS, the machine and
    the CPU features numpy dispatches on (float64 sin / arccos / matmul kernels differ between
    CPUs). A file is this machine's: another machine computes its own."""
    import hashlib
    import platform

    from .. import types

    h = hashlib.sha256(f"procedural v{PROCEDURAL_CACHE_VERSION} {tuple(settings)!r}".encode())
    for mod in (__file__, types.__file__):
        with open(mod, "rb") as f:
            h.update(f.read())
    h.update(_numpy_fingerprint().encode())
    h.update(platform.machine().encode())
    return h.hexdigest()


def _numpy_fingerprint() -> str:
    try:
        from numpy._core import _multiarray_umath as um  # numpy >= 2
    except ImportError:  # pragma: no cover - numpy 1.x
        from numpy.core import _multiarray_umath as um
    feats = sorted(k for k, v in getattr(um, "__cpu_features__", {}).items() if v)
    try:
        blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        blas = f"{blas.get('name')} {blas.get('version')} {blas.get('openblas configuration', '')}"
    except Exception:  # pragma: no cover - a numpy without the dicts form
        blas = "?"
    return f"numpy {np.__version__} | {blas} | {' '.join(feats)}"


def procedural_cache_path(settings: tuple, key: str | None = None):
    """The cache file of `settings` (`key`: its procedural_cache_key, when already computed)."""
    from ..io.files import cache_dir

    return cache_dir("procedural") / f"procedural-{(key or procedural_cache_key(settings))[:40]}.npz"


def _load_cached(settings: _Settings, key: str):
    """The cached (images, depths) of `settings` (whose cache key is `key`), or None (missing,
    unreadable, another key, shape or type: logged at debug level). A file read is marked as used
    (its mtime)."""
    n, w, h = len(settings.views), settings.width, settings.height
    p = procedural_cache_path(settings, key)
    if not p.is_file():
        return None
    try:
        with np.load(p, allow_pickle=False) as z:
            stored, ims, deps = str(z["key"]), z["images"], z["depths"]
        ok = (stored == key and ims.shape == (n, h, w, 3) and deps.shape == (n, h, w)
              and ims.dtype == np.float32 and deps.dtype == np.float32)
    except Exception as e:  # corrupt, truncated or foreign file: render again
        logger.debug("procedural scene cache: %s unreadable (%s); rendering again", p, e)
        return None
    if not ok:
        logger.debug("procedural scene cache: %s is another key, shape or type; rendering again", p)
        return None
    try:
        os.utime(p)
    except OSError:
        pass
    ims.flags.writeable = deps.flags.writeable = False
    return tuple(ims), tuple(deps)


def _store_cached(key: str, views) -> None:
    """Write `views` under the cache key `key` atomically, then keep the `_DISK_KEEP` most recently
    used files (and no temporary file of a write killed an hour or more ago); a refused write
    (read-only or full disk, a size limit) leaves no file and is ignored: the cache only saves time."""
    from ..io.files import atomic_write

    try:
        p = procedural_cache_path(None, key)
        p.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(p, binary=True) as f:
            np.savez(f, key=np.array(key), images=np.stack(views[0]), depths=np.stack(views[1]))
        _prune(p.parent, keep=_DISK_KEEP)
    except OSError as e:
        logger.debug("procedural scene cache: not written (%s)", e)


def _prune(folder, keep: int) -> None:
    import time

    files = sorted(folder.glob("procedural-*.npz"), key=lambda f: f.stat().st_mtime, reverse=True)
    old = files[keep:] + [t for t in folder.glob(".tmp-*.npz") if time.time() - t.stat().st_mtime > 3600]
    for f in old:
        try:
            f.unlink()
        except OSError:
            pass


# }}}
