"""Camera paths for fly-through videos, built from a run's training cameras (numpy only).

    spiral(cams, frames, depth_range)   the LLFF spiral of the forward-facing papers
    ellipse(cams, frames)               a loop around the point the cameras look at (object scenes)
    interpolate(cams, frames)           through the training views in order
    camera_path(kind, cams, frames, points=None, size=None)   any of them, at an image size

Every camera is a `reings.Camera` (OpenCV axes: x right, y down, z forward). Conventions:

* The "average camera" of a set (NeRF's `poses_avg`): centre = mean of the centres, forward =
  the normalised sum of the forward axes, up = minus the normalised sum of the down axes.
* `spiral` follows NeRF's `render_path_spiral` (Mildenhall et al. 2020, the LLFF code that
  RegNeRF, FreeNeRF, DNGaussian and FSGS reuse for their videos), rewritten in OpenCV axes: the
  centre moves on rx·cos t·right + ry·sin t·down + rz·sin(t/2)·forward of the average camera for
  t over two turns, where (rx, ry, rz) are the 90th percentiles of |centre offset| of the
  training cameras along those axes, and every frame looks at the point `focus` ahead of the
  average centre, focus = 1 / (0.25 / near + 0.75 / far) with near = 0.9 × the nearest and
  far = 5 × the farthest scene depth (NeRF: the COLMAP bounds; here `depth_range`).
* `ellipse` is multinerf's `generate_ellipse_path` idea (Barron et al. 2022) without its
  re-orientation of the world: the target is the least-squares point closest to every optical
  axis; the path is an ellipse around it in the plane orthogonal to the cameras' up (`ring_up`:
  the normal of the plane of their centres, else the average up), with the
  semi-axes of the training centres' spread (90th percentile, at least half their mean
  distance), their mean height and half their height range as a sine over one turn, starting at
  the first camera's angle.
* `interpolate` visits the cameras in the given order: centres linearly, rotations by quaternion
  slerp, intrinsics linearly, frames spread over the segments by their length.
"""
from __future__ import annotations

import numpy as np

from .types import Camera

PATHS = ("spiral", "ellipse", "interpolate")


def _normalize(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    if not n > 1e-12:
        raise ValueError("camera path: degenerate direction (the cameras' axes cancel out)")
    return v / n


def look_at(center, target, up, K, width: int, height: int) -> Camera:
    """The camera at `center` looking at `target`, its image up as close to `up` as possible."""
    f = _normalize(np.asarray(target, np.float64) - center)
    right = np.cross(f, up)
    if np.linalg.norm(right) < 1e-9:  # looking along up: any right will do
        right = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 1.0, 0.0])
    right = _normalize(right)
    down = np.cross(f, right)
    return from_axes(center, right, down, f, K, width, height)


def from_axes(center, right, down, forward, K, width: int, height: int) -> Camera:
    R = np.stack([right, down, forward])  # world-to-camera rotation: rows are the camera axes
    V = np.eye(4)
    V[:3, :3] = R
    V[:3, 3] = -R @ np.asarray(center, np.float64)
    return Camera(np.asarray(K, np.float64), V, int(width), int(height))


def average_camera(cams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(centre, right, down, forward) of the average camera (module docstring)."""
    c = np.mean([cam.center for cam in cams], axis=0)
    fwd = _normalize(np.sum([cam.viewmat[2, :3] for cam in cams], axis=0))
    up = -_normalize(np.sum([cam.viewmat[1, :3] for cam in cams], axis=0))
    right = _normalize(np.cross(fwd, up))
    down = np.cross(fwd, right)
    return c, right, down, fwd


def depth_range(cams, points, weights=None) -> tuple[float, float]:
    """(near, far) depths of `points` in front of the average camera: the 1st and 99th
    percentiles (weighted by `weights`, e.g. the Gaussians' opacities)."""
    c, _, _, fwd = average_camera(cams)
    z = (np.asarray(points, np.float64) - c) @ fwd
    w = np.ones_like(z) if weights is None else np.asarray(weights, np.float64)
    keep = (z > 1e-6) & (w > 0) & np.isfinite(z)
    if keep.sum() < 2:
        raise ValueError("camera path: fewer than 2 scene points in front of the cameras")
    z, w = z[keep], w[keep]
    order = np.argsort(z)
    cw = np.cumsum(w[order]) / w.sum()
    pick = lambda q: float(z[order][min(np.searchsorted(cw, q), len(z) - 1)])  # noqa: E731
    return pick(0.01), pick(0.99)


def spiral(cams, frames: int, near_far: tuple[float, float], rots: float = 2.0, zrate: float = 0.5,
           radius_percentile: float = 90.0) -> list[Camera]:
    """NeRF's LLFF spiral (module docstring), with the first camera's intrinsics and size."""
    c, right, down, fwd = average_camera(cams)
    near, far = near_far
    if not (0 < near <= far and np.isfinite(far)):
        raise ValueError(f"camera path: bad depth range {near_far}")
    focus = 1.0 / (0.25 / (0.9 * near) + 0.75 / (5.0 * far))
    off = np.array([cam.center - c for cam in cams])
    rads = np.percentile(np.abs(off @ np.stack([right, down, fwd]).T), radius_percentile, axis=0)
    if not np.any(rads > 0):  # a single position: a small circle of 1 % of the focus distance
        rads = np.array([0.01, 0.01, 0.0]) * focus
    target = c + focus * fwd
    up = -down
    cam0 = cams[0]
    out = []
    for t in np.linspace(0.0, 2 * np.pi * rots, frames, endpoint=False):
        pos = c + rads[0] * np.cos(t) * right + rads[1] * np.sin(t) * down + rads[2] * np.sin(t * zrate) * fwd
        out.append(look_at(pos, target, up, cam0.K, cam0.width, cam0.height))
    return out


def focus_point(cams) -> np.ndarray:
    """The point closest (least squares) to every camera's optical axis."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cams:
        d = cam.viewmat[2, :3]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    if np.linalg.cond(A) > 1e8:  # parallel axes: a point ahead of the average camera
        c, _, _, fwd = average_camera(cams)
        dist = np.mean([np.linalg.norm(cam.center - c) for cam in cams]) or 1.0
        return c + 4.0 * dist * fwd
    return np.linalg.solve(A, b)


def ring_up(cams) -> np.ndarray:
    """The up direction of cameras placed around an object: the normal of the plane through their
    centres (3+ cameras not on a line), else the average camera's up made orthogonal to the line
    through them; oriented like the average camera's up."""
    _, _, down, _ = average_camera(cams)
    u0 = -down
    P = np.array([cam.center for cam in cams])
    if len(P) < 2:
        return u0
    _, sv, Vt = np.linalg.svd(P - P.mean(0))
    if len(P) >= 3 and sv[1] > 1e-6 * sv[0]:
        n = Vt[2] * np.sign(Vt[2] @ u0 or 1.0)
        if n @ u0 > 0.5:  # a plane of centres roughly level with the cameras' own up
            return n
    d = Vt[0]
    return _normalize(u0 - (u0 @ d) * d)


def ellipse(cams, frames: int) -> list[Camera]:
    """A loop around the cameras' focus point (module docstring)."""
    target = focus_point(cams)
    _, right, _, _ = average_camera(cams)
    up = ring_up(cams)
    rel = np.array([cam.center - target for cam in cams])
    h = rel @ up
    q = rel - np.outer(h, up)  # horizontal offsets
    e1 = right - (right @ up) * up
    e1 = _normalize(e1)
    e2 = np.cross(up, e1)
    a1, a2 = np.abs(q @ e1), np.abs(q @ e2)
    floor = 0.5 * np.mean(np.linalg.norm(q, axis=1))
    if not floor > 0:
        raise ValueError("camera path: the cameras sit on the axis of their focus point; use spiral or interpolate")
    ra, rb = max(np.percentile(a1, 90), floor), max(np.percentile(a2, 90), floor)
    t0 = np.arctan2((q[0] @ e2) / rb, (q[0] @ e1) / ra)
    hm, hr = float(np.mean(h)), float(np.ptp(h)) / 2
    cam0 = cams[0]
    out = []
    for t in t0 + np.linspace(0.0, 2 * np.pi, frames, endpoint=False):
        pos = target + ra * np.cos(t) * e1 + rb * np.sin(t) * e2 + (hm + hr * np.sin(t - t0)) * up
        out.append(look_at(pos, target, up, cam0.K, cam0.width, cam0.height))
    return out


def _quat(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    m = np.asarray(R, np.float64)
    w = np.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = np.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2
    y = np.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2
    z = np.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2
    x = np.copysign(x, m[2, 1] - m[1, 2])
    y = np.copysign(y, m[0, 2] - m[2, 0])
    z = np.copysign(z, m[1, 0] - m[0, 1])
    return _normalize([w, x, y, z])


def _rot(q) -> np.ndarray:
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def slerp(q0, q1, t: float) -> np.ndarray:
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    d = float(q0 @ q1)
    if d < 0:  # the short way round
        q1, d = -q1, -d
    if d > 0.9995:
        return _normalize(q0 + t * (q1 - q0))
    th = np.arccos(d)
    return (np.sin((1 - t) * th) * q0 + np.sin(t * th) * q1) / np.sin(th)


def interpolate(cams, frames: int) -> list[Camera]:
    """Through the cameras in order, first to last (module docstring)."""
    if len(cams) < 2:
        raise ValueError("camera path: interpolate needs at least 2 cameras")
    centers = [cam.center for cam in cams]
    seg = np.array([np.linalg.norm(b - a) for a, b in zip(centers[:-1], centers[1:])])
    if not seg.sum() > 0:
        seg = np.ones(len(cams) - 1)
    s = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    out = []
    for u in np.linspace(0.0, 1.0, frames):
        i = min(int(np.searchsorted(s, u, side="right")) - 1, len(cams) - 2)
        t = 0.0 if s[i + 1] == s[i] else (u - s[i]) / (s[i + 1] - s[i])
        a, b = cams[i], cams[i + 1]
        R = _rot(slerp(_quat(a.viewmat[:3, :3]), _quat(b.viewmat[:3, :3]), t))
        c = (1 - t) * a.center + t * b.center
        K = (1 - t) * a.K + t * b.K
        out.append(from_axes(c, R[0], R[1], R[2], K, a.width, a.height))
    return out


def resize(cam: Camera, width: int, height: int) -> Camera:
    """`cam` at another image size (intrinsics scaled per axis)."""
    sx, sy = width / cam.width, height / cam.height
    K = cam.K.copy()
    K[0] *= sx
    K[1] *= sy
    return Camera(K, cam.viewmat, int(width), int(height))


MAX_FRAMES = 100_000  # a path's frames are rendered into memory before they are written


def camera_path(kind: str, cams, frames: int, points=None, weights=None,
                size: tuple[int, int] | None = None) -> list[Camera]:
    """`frames` cameras along path `kind` ('spiral', 'ellipse', 'interpolate') built from `cams`
    (the training cameras); `points` (and `weights`) give the spiral its depth range (a model's
    Gaussian centres and opacities); `size` = (width, height), default the first camera's."""
    if kind not in PATHS:
        raise ValueError(f"camera path: unknown path {kind!r} (one of {', '.join(PATHS)})")
    if int(frames) != frames or not 1 <= frames <= MAX_FRAMES:
        raise ValueError(f"camera path: frames must be a positive integer <= {MAX_FRAMES} (about an hour at 30 "
                         f"frames/s; every frame is held in memory), got {frames!r}")
    cams = list(cams)
    if not cams:
        raise ValueError("camera path: no cameras to build it from")
    if kind == "spiral":
        if points is None:
            raise ValueError("camera path: spiral needs scene points for its depth range")
        path = spiral(cams, int(frames), depth_range(cams, points, weights))
    elif kind == "ellipse":
        path = ellipse(cams, int(frames))
    else:
        path = interpolate(cams, int(frames))
    if size is not None:
        path = [resize(c, size[0], size[1]) for c in path]
    return path
