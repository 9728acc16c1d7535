"""NeRF-synthetic (Blender) scenes: `transforms_{train,val,test}.json`; nerfstudio scenes: one
`transforms.json` with pinhole intrinsics and OpenCV distortion (`load_nerfstudio`).

Each frame's `transform_matrix` is camera-to-world with OpenGL/Blender camera axes (x right,
y up, z backward); OpenCV's are (x right, y down, z forward), so c2w_cv = c2w_gl @ diag(1,-1,-1,1).
Focal length fx = fy = 0.5 W / tan(0.5 camera_angle_x) (or `fl_x`/`fl_y`/`cx`/`cy` when the
file gives them, as nerfstudio-style transforms.json do); principal point (W/2, H/2).
RGBA images are composited over `white_background` (the few-shot papers' choice) and the alpha
is kept as the mask. The split each image came from is kept in `Scene.splits`.
"""
from __future__ import annotations

import json
import os

import numpy as np

from . import images as imgs
from .types import Scene, SceneError, make_camera

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _read_json(path: str) -> dict:
    try:
        with open(path) as f:
            return json.load(f)
    except OSError as e:
        raise SceneError(f"{path}: cannot read ({e})") from e
    except json.JSONDecodeError as e:
        raise SceneError(f"{path}: invalid JSON ({e})") from e


def load_blender(path: str, splits=("train", "val", "test"), white_background: bool = True,
                 downscale: int = 1) -> Scene:
    """A NeRF-synthetic scene folder as a `Scene` (all listed splits, in file order per split)."""
    files = [(s, os.path.join(path, f"transforms_{s}.json")) for s in splits]
    files = [(s, f) for s, f in files if os.path.isfile(f)]
    if not files and os.path.isfile(os.path.join(path, "transforms.json")):
        files = [("train", os.path.join(path, "transforms.json"))]
    if not files:
        raise SceneError(f"{path}: no transforms_*.json")
    ims, cams, names, masks, split_of = [], [], [], [], []
    for split, jpath in files:
        meta = _read_json(jpath)
        for k, fr in enumerate(_frames(meta, jpath)):
            rgb, alpha, cam, ipath = _frame_view(path, meta, fr, f"{jpath} frame {k}", white_background, downscale)
            ims.append(rgb)
            cams.append(cam)
            names.append(f"{split}/{os.path.basename(ipath)}")
            masks.append(alpha if alpha is not None else np.ones(rgb.shape[:2], np.float32))
            split_of.append(split)
    return Scene(ims, cams, names, kind="blender", masks=masks, splits=split_of, source=path,
                 meta={"white_background": bool(white_background)})


def load_nerfstudio(path: str, factor: int = 1, white_background: bool = True) -> Scene:
    """A nerfstudio scene (one `transforms.json`: `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` and the
    distortion `k1`..`k4`, `p1`, `p2` globally or per frame; `camera_model` PINHOLE, OPENCV or
    SIMPLE_RADIAL/RADIAL) as a `Scene` sorted by image name, kind "nerfstudio" (the LLFF protocol:
    every 8th image held out). OPENCV distortion is undone with OpenCV (the undistorted image
    keeps only valid pixels, `getOptimalNewCameraMatrix` with alpha 0); fisheye models are refused."""
    jpath = os.path.join(path, "transforms.json")
    meta = _read_json(jpath)
    model = str(meta.get("camera_model", "OPENCV")).upper()
    if "FISHEYE" in model or model in ("EQUIRECTANGULAR",):
        raise SceneError(f"{jpath}: camera_model {model} is not supported (pinhole and OPENCV distortion only); "
                         "undistort the images first, or run `reings process` on them")
    views = []
    for k, fr in enumerate(_frames(meta, jpath)):
        rgb, alpha, cam, ipath = _frame_view(path, meta, fr, f"{jpath} frame {k}", white_background, factor)
        views.append((os.path.relpath(ipath, path), rgb, cam, alpha))
    views.sort(key=lambda v: v[0])
    names = [v[0] for v in views]
    if len(set(names)) != len(names):
        raise SceneError(f"{jpath}: two frames name the same image")
    return Scene([v[1] for v in views], [v[2] for v in views], names, kind="nerfstudio",
                 masks=None if all(v[3] is None for v in views) else
                 [v[3] if v[3] is not None else np.ones(v[1].shape[:2], np.float32) for v in views],
                 source=path, meta={"white_background": bool(white_background), "camera_model": model})


DISTORTION = ("k1", "k2", "p1", "p2", "k3", "k4")  # OpenCV's order: k1 k2 p1 p2 k3 (k4: RADIAL only)


def _frames(meta, jpath) -> list:
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list) or not frames:
        raise SceneError(f"{jpath}: no 'frames' list")
    return frames


def _intrinsics(meta, fr, w, h, where):
    """(K, OpenCV distortion coefficients or None) of one frame at its loaded size w x h."""
    if "fl_x" in meta or "fl_x" in fr:
        src = {**meta, **{k: v for k, v in fr.items() if k in ("fl_x", "fl_y", "cx", "cy", "w", "h") + DISTORTION}}
        try:
            W0, H0 = float(src.get("w", w)), float(src.get("h", h))
            if not (W0 > 0 and H0 > 0):
                raise ValueError(f"w = {src.get('w')!r}, h = {src.get('h')!r}: the image size must be positive")
            sw, sh = w / W0, h / H0
            fx, fy = float(src["fl_x"]) * sw, float(src.get("fl_y", src["fl_x"])) * sh
            cx = float(src["cx"]) * sw if "cx" in src else w / 2.0
            cy = float(src["cy"]) * sh if "cy" in src else h / 2.0
            d = [float(src.get(k, 0.0)) for k in DISTORTION]
        except (TypeError, ValueError) as e:
            raise SceneError(f"{where}: bad intrinsics ({e})") from e
        if d[5]:
            raise SceneError(f"{where}: k4 = {d[5]} (a fisheye or RADIAL k4 model) is not supported")
        dist = np.array(d[:5]) if any(d) else None
    elif "camera_angle_x" in meta:
        try:
            angle = float(meta["camera_angle_x"])
        except (TypeError, ValueError):
            raise SceneError(f"{where}: camera_angle_x must be a number, got {meta['camera_angle_x']!r}") from None
        if not 0.0 < angle < np.pi:
            raise SceneError(f"{where}: camera_angle_x must lie in (0, pi) radians, got {angle}")
        fx = fy = 0.5 * w / np.tan(0.5 * angle)
        cx, cy, dist = w / 2.0, h / 2.0, None
    else:
        raise SceneError(f"{where}: no camera_angle_x or fl_x")
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), dist


def _frame_view(path, meta, fr, where, white_background, downscale):
    """(rgb, alpha or None, Camera, image path) of one frame of a transforms file."""
    try:
        fp = fr["file_path"]
        M = np.asarray(fr["transform_matrix"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as e:
        raise SceneError(f"{where}: missing or bad field ({e})") from e
    if M.shape != (4, 4):
        raise SceneError(f"{where}: transform_matrix has shape {M.shape}, expected (4, 4)")
    if not np.all(np.isfinite(M)):
        raise SceneError(f"{where}: non-finite (NaN/inf) value in transform_matrix")
    sv = np.linalg.svd(M[:3, :3], compute_uv=False)  # a rotation, up to the small uniform scale exports carry
    if not sv[-1] > 0.0 or sv[0] / sv[-1] > 1.05:
        raise SceneError(f"{where}: transform_matrix's 3x3 part is not a rotation (singular values "
                         f"{', '.join(f'{v:.4g}' for v in sv)})")
    ipath = os.path.normpath(os.path.join(path, fp))
    if not os.path.splitext(ipath)[1]:
        ipath += ".png"
    rgb, alpha = imgs.read_rgba(ipath)
    K, dist = _intrinsics(meta, fr, rgb.shape[1], rgb.shape[0], where)
    if dist is not None:  # undo OpenCV distortion at full size, then downscale
        rgb, alpha, K = _undistort(rgb, alpha, K, dist)
    if downscale > 1:
        h, w = rgb.shape[:2]
        w2, h2 = w // downscale, h // downscale
        rgb = imgs.resize(rgb, w2, h2)
        alpha = None if alpha is None else imgs.resize(alpha[:, :, None], w2, h2)[:, :, 0]
        K = K.copy()
        K[0] *= w2 / w
        K[1] *= h2 / h
    h, w = rgb.shape[:2]
    if alpha is not None:
        bg = 1.0 if white_background else 0.0
        rgb = rgb * alpha[:, :, None] + bg * (1.0 - alpha[:, :, None])
    c2w = M @ GL_TO_CV
    # Blender exports can carry a tiny scale; re-orthonormalise through the SVD
    u, _, vt = np.linalg.svd(c2w[:3, :3])
    R = u @ vt
    V = np.eye(4)
    V[:3, :3] = R.T
    V[:3, 3] = -R.T @ c2w[:3, 3]
    return rgb.astype(np.float32), alpha, make_camera(K, V, w, h, where), ipath


def _undistort(rgb, alpha, K, dist):
    """OpenCV undistortion to a pinhole K' that keeps only valid pixels (alpha 0). OpenCV puts
    pixel centres at integers, reings (and nerfstudio, COLMAP) at +0.5: the principal point
    moves by half a pixel on the way in and back."""
    cv2 = imgs._cv2()
    h, w = rgb.shape[:2]
    shift = np.array([[1.0, 0, -0.5], [0, 1.0, -0.5], [0, 0, 1.0]])
    Kcv = shift @ K
    K2cv, _ = cv2.getOptimalNewCameraMatrix(Kcv, dist, (w, h), 0, (w, h))
    mx, my = cv2.initUndistortRectifyMap(Kcv, dist, None, K2cv, (w, h), cv2.CV_32FC1)
    K2 = np.linalg.inv(shift) @ K2cv
    out = cv2.remap(rgb.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    a = None if alpha is None else cv2.remap(alpha.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                                             borderMode=cv2.BORDER_REPLICATE)
    return np.clip(out, 0, 1), a, K2.astype(np.float64)
