"""cameras.json: a run's cameras in the layout of the 3DGS reference code (Inria), read and written.

One JSON list, one object per camera, the keys of 3DGS's `camera_to_JSON` (scene/cameras.py of
graphdeco-inria/gaussian-splatting, the file SIBR's viewer and most splat tools read):

    id        position in the list
    img_name  image name without its extension
    width, height
    position  camera centre in world coordinates [3]
    rotation  camera-to-world rotation [3][3] (rows), columns = the camera's x (right), y (down),
              z (forward) axes in world coordinates: OpenCV axes, as 3DGS and reings use
    fx, fy    focal lengths in pixels

and three keys of our own that Inria readers ignore: `cx`, `cy` (the principal point in pixels;
a file without them means the image centre, as 3DGS assumes) and `split` ("train" or "test": a
run's test cameras are written too, so a path or a check can use either).

`read_cameras_json` accepts any file of this layout, 3DGS's own included, and names the file and
the entry for every problem.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from ..types import Camera


class CamerasFileError(ValueError):
    """A cameras.json that cannot be used: the message names the file and the entry."""


@dataclass(frozen=True)
class CameraRecord:
    """One entry of a cameras.json: the image name, its split ("train", "test" or "" if the file
    has none) and the pinhole camera."""

    name: str
    split: str
    camera: Camera


def camera_entry(i: int, name: str, cam: Camera, split: str) -> dict:
    """The cameras.json object of `cam` (see the module docstring)."""
    R = cam.viewmat[:3, :3]
    return {"id": int(i), "img_name": os.path.splitext(os.path.basename(str(name)))[0],
            "width": int(cam.width), "height": int(cam.height),
            "position": [float(v) for v in cam.center], "rotation": [[float(v) for v in row] for row in R.T],
            "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "split": split}


def cameras_json(groups) -> list[dict]:
    """The cameras.json list of `groups`, an iterable of (split, names, cameras), ids in order."""
    entries = []
    for split, names, cams in groups:
        for name, cam in zip(names, cams):
            entries.append(camera_entry(len(entries), name, cam, split))
    return entries


def _number(path, i, key, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise CamerasFileError(f"{path}: camera {i}: '{key}' must be a finite number, got {v!r}")
    return float(v)


def _matrix(path, i, key, v, shape) -> np.ndarray:
    try:
        a = np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise CamerasFileError(f"{path}: camera {i}: '{key}' must be numbers of shape {shape}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise CamerasFileError(f"{path}: camera {i}: '{key}' must be finite numbers of shape {shape}, "
                               f"got shape {a.shape}")
    return a


def record_of(entry, path="cameras.json", i: int = 0) -> CameraRecord:
    """A `CameraRecord` from one cameras.json object."""
    if not isinstance(entry, dict):
        raise CamerasFileError(f"{path}: camera {i} is a {type(entry).__name__}, expected an object")
    missing = [k for k in ("width", "height", "position", "rotation", "fx", "fy") if k not in entry]
    if missing:
        raise CamerasFileError(f"{path}: camera {i} lacks {', '.join(repr(k) for k in missing)}")
    w, h = entry["width"], entry["height"]
    if isinstance(w, bool) or isinstance(h, bool) or not isinstance(w, int) or not isinstance(h, int) \
            or w < 1 or h < 1:
        raise CamerasFileError(f"{path}: camera {i}: width and height must be positive integers, got {w!r}x{h!r}")
    fx, fy = _number(path, i, "fx", entry["fx"]), _number(path, i, "fy", entry["fy"])
    if fx <= 0 or fy <= 0:
        raise CamerasFileError(f"{path}: camera {i}: focal lengths must be positive, got fx={fx}, fy={fy}")
    cx = _number(path, i, "cx", entry["cx"]) if "cx" in entry else w / 2
    cy = _number(path, i, "cy", entry["cy"]) if "cy" in entry else h / 2
    C = _matrix(path, i, "position", entry["position"], (3,))
    R = _matrix(path, i, "rotation", entry["rotation"], (3, 3))  # camera-to-world
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) <= 0:
        raise CamerasFileError(f"{path}: camera {i}: 'rotation' is not a proper rotation "
                               f"(det {np.linalg.det(R):.4f})")
    V = np.eye(4)
    V[:3, :3] = R.T
    V[:3, 3] = -R.T @ C
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    name = entry.get("img_name", f"camera_{i:04d}")
    split = entry.get("split", "")
    return CameraRecord(str(name), str(split), Camera(K, V, w, h))


def write_cameras_json(path, groups) -> None:
    """Write `cameras_json(groups)` to `path` atomically (unique temp file, then replace)."""
    from .files import atomic_write

    text = json.dumps(cameras_json(groups), indent=1)
    with atomic_write(path) as f:
        f.write(text + "\n")


def read_cameras_json(path, split: str | None = None) -> list[CameraRecord]:
    """The cameras of a cameras.json (ours or 3DGS's), in file order; `split` keeps only that
    split's entries ("train", "test")."""
    from .files import read_json

    path = os.fspath(path)
    data = read_json(path, f"{path}: cameras file not found", CamerasFileError, "not a JSON file")
    if not isinstance(data, list) or not data:
        raise CamerasFileError(f"{path}: expected a non-empty JSON list of cameras")
    recs = [record_of(e, path, i) for i, e in enumerate(data)]
    if split is not None:
        recs = [r for r in recs if r.split == split]
        if not recs:
            raise CamerasFileError(f"{path}: no camera of split {split!r}")
    return recs
