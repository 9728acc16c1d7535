"""NeRF-synthetic (Blender) scenes: `transforms_{train,val,test}.json`.

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
        frames = meta.get("frames")
        if not isinstance(frames, list) or not frames:
            raise SceneError(f"{jpath}: no 'frames' list")
        for k, fr in enumerate(frames):
            where = f"{jpath} frame {k}"
            try:
                fp = fr["file_path"]
                M = np.asarray(fr["transform_matrix"], dtype=np.float64)
            except (KeyError, TypeError, ValueError) as e:
                raise SceneError(f"{where}: missing or bad field ({e})") from e
            if M.shape != (4, 4):
                raise SceneError(f"{where}: transform_matrix has shape {M.shape}, expected (4, 4)")
            if not np.all(np.isfinite(M)):
                raise SceneError(f"{where}: non-finite (NaN/inf) value in transform_matrix")
            ipath = os.path.normpath(os.path.join(path, fp))
            if not os.path.splitext(ipath)[1]:
                ipath += ".png"
            rgb, alpha = imgs.read_rgba(ipath)
            if downscale > 1:
                h, w = rgb.shape[:2]
                w2, h2 = w // downscale, h // downscale
                rgb = imgs.resize(rgb, w2, h2)
                alpha = None if alpha is None else imgs.resize(alpha[:, :, None], w2, h2)[:, :, 0]
            h, w = rgb.shape[:2]
            if alpha is not None:
                bg = 1.0 if white_background else 0.0
                rgb = rgb * alpha[:, :, None] + bg * (1.0 - alpha[:, :, None])
            if "fl_x" in meta or "fl_x" in fr:
                src = fr if "fl_x" in fr else meta
                sw = w / float(src.get("w", w))
                fx, fy = float(src["fl_x"]) * sw, float(src.get("fl_y", src["fl_x"])) * sw
                cx, cy = float(src.get("cx", w / 2 / sw)) * sw, float(src.get("cy", h / 2 / sw)) * sw
            elif "camera_angle_x" in meta:
                fx = fy = 0.5 * w / np.tan(0.5 * float(meta["camera_angle_x"]))
                cx, cy = w / 2.0, h / 2.0
            else:
                raise SceneError(f"{jpath}: no camera_angle_x or fl_x")
            c2w = M @ GL_TO_CV
            R = c2w[:3, :3]
            # Blender exports can carry a tiny scale; re-orthonormalise through the SVD
            u, _, vt = np.linalg.svd(R)
            R = u @ vt
            V = np.eye(4)
            V[:3, :3] = R.T
            V[:3, 3] = -R.T @ c2w[:3, 3]
            K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
            ims.append(rgb.astype(np.float32))
            cams.append(make_camera(K, V, w, h, where))
            names.append(f"{split}/{os.path.basename(ipath)}")
            masks.append(alpha if alpha is not None else np.ones((h, w), np.float32))
            split_of.append(split)
    return Scene(ims, cams, names, kind="blender", masks=masks, splits=split_of, source=path,
                 meta={"white_background": bool(white_background)})
