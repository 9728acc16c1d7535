"""The import path `reings.data.scene`, kept for callers written before the split.

`Scene`, `SceneError`, `KINDS` and `make_camera` live in `reings.data.types`; `load_scene`,
`detect_format`, `canonical_kind` and `DATASET_ALIASES` in `reings.data.loader`. New code imports
from `reings.data` (or those two modules). Nothing inside `reings.data` imports this module, so it
closes no import cycle.
"""
from __future__ import annotations

from .loader import DATASET_ALIASES, canonical_kind, detect_format, load_scene
from .types import KINDS, Scene, SceneError, make_camera

__all__ = ["KINDS", "Scene", "SceneError", "make_camera", "DATASET_ALIASES", "canonical_kind", "detect_format",
           "load_scene"]
