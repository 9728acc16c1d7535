"""Scenes and few-shot protocols: loaders, splits, the procedural scene, SfM extent.

Light to import (numpy only); cv2 and pycolmap load inside the functions that need them.
"""
from __future__ import annotations

from .scene import KINDS, Scene, SceneError, detect_format, load_scene
from .splits import DTU_EXCLUDED, DTU_TRAIN_IDS, few_shot_split

__all__ = [
    "KINDS", "Scene", "SceneError", "detect_format", "load_scene", "few_shot_split",
    "DTU_TRAIN_IDS", "DTU_EXCLUDED", "make_procedural_scene", "sfm_extent", "SfmExtent",
]


def __getattr__(name):
    if name == "make_procedural_scene":
        from .procedural import make_procedural_scene

        return make_procedural_scene
    if name in ("sfm_extent", "SfmExtent", "frusta_extent"):
        from . import sfm

        return getattr(sfm, name)
    raise AttributeError(f"module 'reings.data' has no attribute {name!r}")
