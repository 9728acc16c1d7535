"""Scenes and few-shot protocols: loaders, splits, the procedural scene, SfM extent.

Layout (imports point down this list, never up, so the package has no import cycle):
  types.py      `Scene`, `SceneError`, `KINDS`, `make_camera` (imports nothing from the package)
  images.py     image files (the only cv2 import), `factor_image_folder`
  cachekey.py, splits.py, stereo.py      helpers with no package imports
  llff.py, colmap.py, dtu.py, blender.py, procedural.py      one format each (llff reads its
                sparse points through colmap)
  loader.py     `load_scene`, `detect_format`, `canonical_kind`: the dispatcher over the formats
  sfm.py, depth_prior.py      SfM extent and depth priors of a loaded scene
  scene.py      the pre-split import path `reings.data.scene` (re-exports types + loader)

Light to import (numpy only); cv2 and pycolmap load inside the functions that need them.
"""
from __future__ import annotations

from .loader import DATASET_ALIASES, canonical_kind, detect_format, load_scene
from .splits import DTU_EXCLUDED, DTU_TRAIN_IDS, few_shot_split
from .types import KINDS, Scene, SceneError, make_camera

__all__ = [
    "KINDS", "Scene", "SceneError", "make_camera", "DATASET_ALIASES", "canonical_kind", "detect_format",
    "load_scene", "few_shot_split",
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
