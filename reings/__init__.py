"""reings: torch-free few-shot novel view synthesis with 3D Gaussians (ReInGS).

`import reings` is light: it imports numpy only. pyopencl, onnxruntime, cv2 and pycolmap are
imported by the modules that need them, on first use. torch is never imported.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it (loaded on first attribute access)
_LAZY = {
    "Gaussians": "reings.types",
    "Camera": "reings.types",
    "RenderOutput": "reings.types",
    "render": "reings.rendering",
    "render_vjp": "reings.rendering",
    "get_backend": "reings.backends",
    "Scene": "reings.data.types",
    "SceneError": "reings.data.types",
    "load_scene": "reings.data.loader",
    "few_shot_split": "reings.data.splits",
    "make_procedural_scene": "reings.data.procedural",
    "sfm_extent": "reings.data.sfm",
    "get_depth_prior": "reings.data.depth_prior",
    "evaluate_images": "reings.metrics",
    "fit": "reings.train",
    "run": "reings.pipeline",
    "reconstruct": "reings.inmemory",
    "render_path": "reings.video",
    "export_run": "reings.export",
    "process_photos": "reings.data.process",
    "read_cameras_json": "reings.io.cameras",
    "RunConfig": "reings.config",
    "ReInGSConfig": "reings.config",
    "OutputConfig": "reings.config",
    "TrainConfig": "reings.config",
    "load_run_config": "reings.config",
}
_SUBMODULES = ("metrics", "pipeline")

__all__ = sorted(_LAZY) + list(_SUBMODULES)


def __getattr__(name):
    if name in _SUBMODULES:
        value = importlib.import_module(f"reings.{name}")
        globals()[name] = value
        return value
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'reings' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
