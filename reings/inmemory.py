"""`reings.reconstruct` (this module: reings.inmemory): the whole method on images and cameras held in memory.

    g = reings.reconstruct(images, cameras, device="cuda")            # -> reings.Gaussians
    g = reings.reconstruct(images, cameras, method="dngaussian", preset="paper", out="runs/x")
    gs = reings.reconstruct(images, cameras, ensemble=2)              # -> [member 0, member 1]

Every view trains (`holdout="none"`); nothing is read from or written to disk unless `out` is
given (then it is a normal run folder: metrics.json, gaussians.ply, cameras.json, renders). The
keywords are `reings.run`'s (RunConfig fields: preset, iterations, seed, depth_prior, ...). By
default no LPIPS and no PSNR probes are computed (they only score the training views here).
"""
from __future__ import annotations

import numpy as np


def as_scene(images, cameras, names=None, bounds=None, kind: str = "colmap"):
    """A `reings.Scene` of in-memory views: images [H,W,3] float in [0, 1] or uint8, one
    `reings.Camera` each (OpenCV axes, world-to-camera viewmat), optional per-view (near, far)
    depth bounds [V, 2] (the scene box falls back to them when SfM finds too few points)."""
    from .data.types import Scene, SceneError

    images, cameras = list(images), list(cameras)
    if len(images) != len(cameras):
        raise SceneError(f"reconstruct: {len(images)} images but {len(cameras)} cameras")
    if len(images) < 2:
        raise SceneError(f"reconstruct: {len(images)} view; at least 2 are needed")
    ims = []
    for i, im in enumerate(images):
        a = np.asarray(im)
        if a.dtype == np.uint8:
            a = a.astype(np.float32) / 255.0
        elif not np.issubdtype(a.dtype, np.floating):
            raise SceneError(f"reconstruct: image {i} has dtype {a.dtype}; pass uint8 or float in [0, 1]")
        a = np.asarray(a, np.float32)
        if a.ndim != 3 or a.shape[2] != 3:
            raise SceneError(f"reconstruct: image {i} has shape {a.shape}, expected (H, W, 3) RGB")
        if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
            raise SceneError(f"reconstruct: image {i} has values outside [0, 1] (or NaN/Inf)")
        ims.append(a)
    names = [f"view{i:03d}.png" for i in range(len(ims))] if names is None else [str(n) for n in names]
    if len(set(names)) != len(names):
        raise SceneError("reconstruct: image names must be unique")
    return Scene(images=ims, cameras=cameras, names=names, kind=kind, bounds=bounds)


def reconstruct(images, cameras, method: str = "reings", device: str = "pocl", names=None, bounds=None,
                out: str | None = None, quiet: bool = True, **config):
    """Fit `method` to every given view; returns the final `reings.Gaussians` (module docstring),
    or for an ensemble (`ensemble=K` > 1, or `recipe="dtu"`, whose reings default is two members)
    the list of its members (`reings.render_path` takes the list and draws their mean image)."""
    from .pipeline import run

    scene = as_scene(images, cameras, names, bounds)
    config.setdefault("with_lpips", False)
    config.setdefault("eval_every", 0)
    res = run(scene=scene, method=method, device=device, holdout="none", out=out or None, quiet=quiet, **config)
    return res.members if len(res.members) > 1 else res.gaussians
