"""LLFF forward-facing scenes: `poses_bounds.npy` (N x 17) and its NeX variant (N x 14 + hwf_cxcy.npy).

Official LLFF row: a 3x5 matrix flattened row-major, [R | t | hwf] with the rotation columns in
LLFF's [down, right, back] order (camera-to-world), hwf = (height, width, focal) at the full
capture resolution, then (near, far). COLMAP's camera axes are [right, down, forward], so the
OpenCV camera-to-world rotation is [col1, col0, -col2]; the world frame is COLMAP's, unchanged
(3DGS-family convention, docs/method.md §4.1: no recentering, no rescale, no NDC), so the dataset's
`sparse/0/points3D.bin` projects into the images with these cameras. The principal point is the
image centre (W/2, H/2) in the +0.5 pixel convention: COLMAP's cameras.bin for fern/flower has
cx = 2016 = 4032/2, and its focal length equals the hwf focal.

NeX row: a 3x4 camera-to-world matrix in the same [down, right, back, t] order, then (near, far);
`hwf_cxcy.npy` holds (h, w, fx, fy, cx, cy) of the stored (undistorted) images.

Images: `images_{factor}/` if present, else `images/` area-resized; intrinsics are scaled by the
actual size ratio. Images are sorted by name and matched to rows in order (LLFF's rule).
"""
from __future__ import annotations

import os

import numpy as np

from . import images as imgs
from .types import Scene, SceneError, make_camera

# NeX-format folders here store images at 1/4 of the original LLFF capture (about 1008 x 756),
# so `factor` (counted from the original capture) maps to an extra downscale of 4 / factor.
NEX_STORED_FACTOR = 4


def llff_to_viewmat(c2w_llff: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 (OpenCV axes) from a 3x4 camera-to-world in LLFF [down, right, back, t] order."""
    c2w_llff = np.asarray(c2w_llff, dtype=np.float64)
    c2w = np.eye(4)
    c2w[:3, 0] = c2w_llff[:, 1]  # right
    c2w[:3, 1] = c2w_llff[:, 0]  # down
    c2w[:3, 2] = -c2w_llff[:, 2]  # forward = -back
    c2w[:3, 3] = c2w_llff[:, 3]
    R = c2w[:3, :3]
    V = np.eye(4)
    V[:3, :3] = R.T
    V[:3, 3] = -R.T @ c2w[:3, 3]
    return V


def _load_npy(path: str, ncols: int) -> np.ndarray:
    if not os.path.isfile(path):
        raise SceneError(f"{path}: file not found")
    try:
        a = np.load(path, allow_pickle=False)
    except Exception as e:
        raise SceneError(f"{path}: cannot read .npy ({e})") from e
    _check_real(path, a)
    if a.ndim != 2 or a.shape[1] != ncols:
        raise SceneError(f"{path}: expected shape (N, {ncols}), got {a.shape}")
    return a.astype(np.float64)


def _check_real(path: str, a: np.ndarray) -> None:
    """Real numbers only: complex, string, object, structured and boolean arrays are named errors
    (a complex array was cast with only a numpy warning, its imaginary part dropped)."""
    if a.dtype.kind not in "fiu":
        raise SceneError(f"{path}: expected real numbers, got an array of dtype {a.dtype}")


def _check_bounds(where: str, near_far) -> None:
    """A row's (near, far) depth bounds: 0 < near < far (the scene box falls back to them)."""
    near, far = (float(v) for v in near_far)
    if not 0.0 < near < far:
        raise SceneError(f"{where}: bad near/far bounds ({near:g}, {far:g}); need 0 < near < far")


def _read_views(folder: str, names: list[str], scale: float):
    out = []
    for n in names:
        im = imgs.read_image(os.path.join(folder, n))
        if scale != 1.0:
            h, w = im.shape[:2]
            im = imgs.resize(im, max(1, round(w * scale)), max(1, round(h * scale)))
        out.append(im)
    return out


def _points(path: str):
    """Sparse points of the dataset's own (full-view) COLMAP model, or (None, None)."""
    from .colmap import find_model_dir, read_points

    if find_model_dir(path) is None:
        return None, None
    xyz, rgb = read_points(path)
    return (xyz, rgb) if len(xyz) else (None, None)


def load_llff(path: str, factor: int = 8, load_points: bool = True) -> Scene:
    """An official LLFF scene folder (poses_bounds.npy N x 17, images_{factor}/) as a `Scene`."""
    pb_path = os.path.join(path, "poses_bounds.npy")
    pb = _load_npy(pb_path, 17)
    folder, scale = imgs.factor_image_folder(path, factor)
    names = imgs.list_images(folder)
    if len(names) != len(pb):
        raise SceneError(f"{pb_path}: {len(pb)} poses but {len(names)} images in {folder}")
    ims = _read_views(folder, names, scale)
    poses = pb[:, :15].reshape(-1, 3, 5)
    cams = []
    for i, (im, P, n) in enumerate(zip(ims, poses, names)):
        where = f"{pb_path} row {i} ({n})"
        if not np.all(np.isfinite(pb[i])):
            raise SceneError(f"{where}: non-finite (NaN/inf) value in the pose or bounds")
        _check_bounds(where, pb[i, 15:17])
        H0, W0, f0 = P[:, 4]
        h, w = im.shape[:2]
        if H0 <= 0 or W0 <= 0 or f0 <= 0:
            raise SceneError(f"{where}: bad hwf {P[:, 4].tolist()}")
        if abs((w / h) / (W0 / H0) - 1.0) > 0.02:
            raise SceneError(f"{where}: image is {w}x{h} but hwf says {W0:g}x{H0:g} (aspect mismatch)")
        sx, sy = w / W0, h / H0
        K = np.array([[f0 * sx, 0, w / 2.0], [0, f0 * sy, h / 2.0], [0, 0, 1]])
        cams.append(make_camera(K, llff_to_viewmat(P[:, :4]), w, h, where))
    bounds = pb[:, 15:17]
    xyz, rgb = _points(path) if load_points else (None, None)
    return Scene(ims, cams, names, kind="llff", bounds=bounds, points=xyz, point_colors=rgb,
                 points_from_all_views=xyz is not None, source=path, meta={"factor": factor})


def load_llff_nex(path: str, factor: int = 8, load_points: bool = True) -> Scene:
    """A NeX-format LLFF folder (poses_bounds.npy N x 14, hwf_cxcy.npy, images/) as a `Scene`.

    `factor` counts from the original LLFF capture (see NEX_STORED_FACTOR): 8 gives about 501x376.
    """
    pb_path = os.path.join(path, "poses_bounds.npy")
    pb = _load_npy(pb_path, 14)
    hwf_path = os.path.join(path, "hwf_cxcy.npy")
    if not os.path.isfile(hwf_path):
        raise SceneError(f"{hwf_path}: file not found")
    try:
        hwf = np.load(hwf_path, allow_pickle=False)
    except Exception as e:
        raise SceneError(f"{hwf_path}: cannot read .npy ({e})") from e
    _check_real(hwf_path, hwf)
    hwf = hwf.astype(np.float64).ravel()
    if hwf.shape != (6,) or not np.all(np.isfinite(hwf)) or np.any(hwf[:4] <= 0):
        raise SceneError(f"{hwf_path}: expected 6 finite values (h, w, fx, fy, cx, cy), got {hwf.tolist()}")
    H0, W0, fx, fy, cx, cy = hwf
    d = os.path.join(path, f"images_{factor}")
    if os.path.isdir(d):
        folder, scale = d, None  # sizes read from the files
    else:
        folder = os.path.join(path, "images")
        if not os.path.isdir(folder):
            raise SceneError(f"{path}: no images/ folder")
        scale = min(1.0, NEX_STORED_FACTOR / float(factor)) if factor else 1.0
    names = imgs.list_images(folder)
    if len(names) != len(pb):
        raise SceneError(f"{pb_path}: {len(pb)} poses but {len(names)} images in {folder}")
    ims = _read_views(folder, names, scale or 1.0)
    cams = []
    for i, (im, row, n) in enumerate(zip(ims, pb, names)):
        where = f"{pb_path} row {i} ({n})"
        if not np.all(np.isfinite(row)):
            raise SceneError(f"{where}: non-finite (NaN/inf) value in the pose or bounds")
        _check_bounds(where, row[12:14])
        h, w = im.shape[:2]
        sx, sy = w / W0, h / H0
        K = np.array([[fx * sx, 0, cx * sx], [0, fy * sy, cy * sy], [0, 0, 1]])
        cams.append(make_camera(K, llff_to_viewmat(row[:12].reshape(3, 4)), w, h, where))
    xyz, rgb = _points(path) if load_points else (None, None)
    return Scene(ims, cams, names, kind="llff_nex", bounds=pb[:, 12:14], points=xyz, point_colors=rgb,
                 points_from_all_views=xyz is not None, source=path, meta={"factor": factor})
