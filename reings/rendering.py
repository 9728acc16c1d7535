"""`render` and `render_vjp`: the public entry points of the splatting core; `gaussian_importance`,
ReInGS's Omega_G summed over views through `render`.

They validate arguments, pick the backend for `device` (reings.backends.get_backend) and call its
fused path. Nothing here knows about OpenCL.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .types import FIELDS, Camera, Gaussians, RenderOutput


def _check_common(gaussians, camera, background, near):
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"gaussians must be reings.Gaussians, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be reings.Camera, got {type(camera).__name__}")
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValueError(f"background must be 3 finite numbers, got {background!r}")
    if not (np.isfinite(near) and near > 0):
        raise ValueError(f"near must be a positive finite number, got {near!r}")
    return tuple(float(x) for x in bg)


def _check_image(name, a, camera, channels):
    if a is None:
        return None
    a = np.ascontiguousarray(np.asarray(a, dtype=np.float32))
    shape = (camera.height, camera.width) + ((channels,) if channels else ())
    if a.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or Inf")
    return a


def render(gaussians: Gaussians, camera: Camera, device: str = "pocl",
           background: Sequence[float] = (0.0, 0.0, 0.0), near: float = 0.01,
           opacity_override: float | None = None, want_importance: bool = False) -> RenderOutput:
    """Render `gaussians` from `camera`. Returns `.rgb` [H,W,3], `.depth` [H,W], `.alpha` [H,W].

    opacity_override: if given, every Gaussian blends with this opacity (e.g. 0.99 for the "hard"
        depth render of DNGaussian / ReInGS IVPS).
    want_importance: also return `.importance` [N], each Gaussian's sum of alpha*T over the pixels
        where it blends (ReInGS's Omega_G for one view).
    """
    from .backends import get_backend

    bg = _check_common(gaussians, camera, background, near)
    if opacity_override is not None and not (0.0 < float(opacity_override) <= 1.0):
        raise ValueError(f"opacity_override must be in (0, 1], got {opacity_override!r}")
    return get_backend(device).render(gaussians, camera, background=bg, near=float(near),
                                      opacity_override=opacity_override, want_importance=want_importance)


def gaussian_importance(g, cameras, device, bg, near) -> np.ndarray:
    """Omega_G (Eq. 7): per Gaussian, the sum over `cameras` and their pixels of alpha*T where it
    blends; float64 [N]. The basis of CVPS, of the final prune and of DensifyConfig.prune_unseen
    (pass training cameras only; reings.reinit re-exports it)."""
    from .backends import get_backend
    from .backends.base import render_importance

    cameras = list(cameras)
    for cam in cameras:  # render's checks, once per camera
        bg = _check_common(g, cam, bg, near)
    return render_importance(get_backend(device), g, cameras, bg, near)


def render_vjp(gaussians: Gaussians, camera: Camera, v_rgb, v_depth=None, v_alpha=None,
               device: str = "pocl", background: Sequence[float] = (0.0, 0.0, 0.0), near: float = 0.01,
               opacity_override: float | None = None, grad_fields: Sequence[str] | None = None) -> Gaussians:
    """Vector-Jacobian product of `render`: a `Gaussians` holding dL/d(raw field) for
    L = sum(v_rgb * rgb) + sum(v_depth * depth) + sum(v_alpha * alpha).

    grad_fields: restrict which fields receive gradient (others are returned as zeros), e.g.
        ("means",) for DNGaussian's hard depth term, ("opacity_logits",) for the soft one.
        With opacity_override set, opacity_logits never receive gradient.
    """
    from .backends import get_backend

    bg = _check_common(gaussians, camera, background, near)
    v_rgb = _check_image("v_rgb", v_rgb, camera, 3)
    v_depth = _check_image("v_depth", v_depth, camera, 0)
    v_alpha = _check_image("v_alpha", v_alpha, camera, 0)
    if grad_fields is not None:
        bad = [f for f in grad_fields if f not in FIELDS]
        if bad:
            raise ValueError(f"grad_fields: unknown fields {bad}; valid: {FIELDS}")
        grad_fields = tuple(grad_fields)
    return get_backend(device).render_vjp(gaussians, camera, v_rgb, v_depth, v_alpha, background=bg,
                                          near=float(near), opacity_override=opacity_override,
                                          grad_fields=grad_fields)
