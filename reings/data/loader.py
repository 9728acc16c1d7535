"""Loading a scene folder: format detection (`detect_format`) and dispatch (`load_scene`).

The only module that knows every dataset format by name. Each format's parsing lives in its own
module (`llff.py`, `colmap.py`, `dtu.py`, `blender.py`, `procedural.py`); they are imported here
on first use, so `import reings.data` stays light. The `Scene` type they return is in `types.py`.
"""
from __future__ import annotations

import os

from .types import KINDS, Scene, SceneError

# other names a user may pass as `dataset=` -> the kind in `KINDS`
DATASET_ALIASES = {"nex": "llff_nex", "nerf_synthetic": "blender", "synthetic": "blender", "idr": "dtu", "neus": "dtu"}


def canonical_kind(dataset: str) -> str:
    """The `KINDS` entry a user-given dataset name stands for (case-insensitive, aliases resolved)."""
    kind = DATASET_ALIASES.get(str(dataset).lower(), str(dataset).lower())
    if kind not in KINDS:
        raise SceneError(f"unknown dataset {kind!r}; known: {', '.join(KINDS)}")
    return kind


def detect_format(path: str) -> str:
    """The dataset kind of folder `path` (see `KINDS`), from the files it holds."""
    if not os.path.exists(path):
        raise SceneError(f"{path}: scene folder not found")
    if not os.path.isdir(path):
        raise SceneError(f"{path}: not a folder")
    has = lambda *p: os.path.exists(os.path.join(path, *p))  # noqa: E731
    if has("transforms_train.json"):
        return "blender"
    if has("transforms.json"):  # nerfstudio's single file (intrinsics fl_x...), else a one-split Blender scene
        from .blender import _read_json

        meta = _read_json(os.path.join(path, "transforms.json"))
        frames = meta.get("frames") if isinstance(meta, dict) else None
        first = frames[0] if isinstance(frames, list) and frames and isinstance(frames[0], dict) else {}
        return "nerfstudio" if "fl_x" in meta or "fl_x" in first or "camera_model" in meta else "blender"
    if has("cameras_sphere.npz") or has("cameras.npz"):
        return "dtu"
    from .dtu import find_regnerf_calibration

    if find_regnerf_calibration(path) is not None:
        return "dtu"
    if has("poses_bounds.npy"):
        return "llff_nex" if has("hwf_cxcy.npy") else "llff"
    for sub in (("sparse", "0"), ("sparse",), ()):
        for f in ("cameras.bin", "cameras.txt"):
            if has(*sub, f):
                return "colmap"
    raise SceneError(
        f"{path}: cannot detect the dataset format (no transforms_train.json, transforms.json, cameras_sphere.npz, "
        "Calibration/cal18, poses_bounds.npy or COLMAP sparse/0); pass dataset=..."
    )


def load_scene(path=None, dataset: str | None = None, factor: int | None = 8, **kwargs) -> Scene:
    """Load a scene folder as a `Scene`; `dataset=None` detects the format.

    Args:
        path: scene folder, or None / "procedural" for the built-in procedural scene.
        dataset: one of "llff", "llff_nex", "colmap", "dtu", "blender", "nerfstudio", "procedural" (or None).
        factor: downsampling factor (None = the protocol's: 8 for LLFF/NeX/COLMAP, 4 for DTU).
            LLFF: reads `images_{factor}/` (or area-resizes `images/`); 8 -> 504x378.
            NeX: counted from the original LLFF capture (stored images are 1/4 of it).
            COLMAP: `images_{factor}/` if present, else `images/` resized by 1/factor.
            DTU: counted from 1600x1200, and the default 8 is read as the protocol's 4
            (400x300), since 8 is LLFF's default; pass `dtu_factor=` for another DTU size.
            nerfstudio: the images (undistorted first) are downscaled by `factor`, as COLMAP's.
            Blender/procedural: ignored.
        **kwargs: passed to the format's loader (e.g. `white_background` for blender).
    """
    if dataset is not None:
        dataset = canonical_kind(dataset)
    if dataset == "procedural" or (dataset is None and (path is None or str(path) == "procedural")):
        from .procedural import make_procedural_scene

        return make_procedural_scene(**kwargs)
    if path is None:
        raise SceneError("load_scene: path is required for dataset " + repr(dataset))
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"load_scene: path must be a folder path (str or os.PathLike), got {path!r}")
    path = os.fspath(path)
    kind = dataset or detect_format(path)
    if not os.path.isdir(path):
        raise SceneError(f"{path}: scene folder not found")
    if kind == "dtu":
        from .dtu import load_dtu

        dtu_factor = kwargs.pop("dtu_factor", 4 if factor in (None, 8) else factor)
        return load_dtu(path, factor=dtu_factor, **kwargs)
    factor = 8 if factor is None else int(factor)
    if kind == "llff":
        from .llff import load_llff

        return load_llff(path, factor=factor, **kwargs)
    if kind == "llff_nex":
        from .llff import load_llff_nex

        return load_llff_nex(path, factor=factor, **kwargs)
    if kind == "colmap":
        from .colmap import load_colmap_scene

        return load_colmap_scene(path, factor=factor, **kwargs)
    if kind == "blender":
        from .blender import load_blender

        return load_blender(path, **kwargs)
    if kind == "nerfstudio":
        from .blender import load_nerfstudio

        return load_nerfstudio(path, factor=factor, **kwargs)
    raise SceneError(f"unknown dataset {kind!r}")  # pragma: no cover
