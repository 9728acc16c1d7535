"""The stage contract shared by every backend (reference float64 numpy, OpenCL, later Warp).

A render is the stage sequence

    project_fwd -> bin -> rasterize_fwd            (forward)
    rasterize_bwd -> isect_reduce -> project_bwd   (backward, inside the backend)

and each stage has the same name in `kernels/<stage>.cl`, in every backend class, in the float64
reference (`reings.backends.reference`) and in `tests/test_<stage>.py`.  The dataclasses below are
the host-side (numpy) view of what passes between stages; the OpenCL backend keeps the same arrays
on the device and only materialises these views for tests and debugging.

Index spaces (names follow brush's `x_from_y` rule):
  gid    Gaussian index, 0..N-1 (input order)
  rank   position of a *visible* Gaussian in (depth t_z, gid) order, 0..V-1
  emit   slot of one (Gaussian, tile) intersection in emit order: ranks in order, each Gaussian's
         tiles row-major (ty outer, tx inner); rank r owns slots [offset_from_rank[r], offset_from_rank[r+1])
  isect  position in the list sorted by (tile, depth, gid); tile t owns [tile_ranges[t,0], tile_ranges[t,1])
  tile   ty * tiles_x + tx, tiles of 16x16 pixels
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from ..types import Camera, Gaussians, RenderOutput

TILE_SIZE = 16
ALPHA_MIN = 1.0 / 255.0  # a pair with alpha below this is skipped (3DGS)
ALPHA_MAX = 0.99  # alpha clamp; no gradient flows through the clamp
T_MIN = 1e-4  # a pixel stops *before* the Gaussian that would make T*(1-alpha) < T_MIN
EPS2D = 0.3  # low-pass dilation added to the 2D covariance diagonal
CLAMP_GUARD = 0.3  # Jacobian guard band, fraction of tan(fov/2) (gsplat)
V_RECORD = 10  # floats per intersection gradient record, see `rasterize_bwd`


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """(tiles_x, tiles_y) for an image."""
    return (width + TILE_SIZE - 1) // TILE_SIZE, (height + TILE_SIZE - 1) // TILE_SIZE


@dataclass
class Projected:
    """Output of `project_fwd`, one row per Gaussian (gid). Culled rows have radii == 0 and an
    empty tile_rect (all four zeros); their other fields are zero."""

    means2d: np.ndarray  # [N, 2] (u, v) pixel coordinates
    conics: np.ndarray  # [N, 3] (A, B, C): power = -0.5*(A dx^2 + C dy^2) - B dx dy
    depths: np.ndarray  # [N] camera-space t_z
    radii: np.ndarray  # [N] int32, 0 = culled
    tile_rect: np.ndarray  # [N, 4] int32 (tx0, ty0, tx1, ty1), half-open, clamped to the grid
    colors: np.ndarray  # [N, 3] SH colour + 0.5, clamped at 0
    opacities: np.ndarray  # [N] effective opacity: sigmoid(logit), or the override constant


@dataclass
class Bins:
    """Output of `bin`: the per-tile depth-ordered Gaussian lists."""

    gid_from_rank: np.ndarray  # [V] int32, visible Gaussians in (depth, gid) order
    offset_from_rank: np.ndarray  # [V + 1] int32, exclusive scan of tiles touched, in rank order
    gid_from_isect: np.ndarray  # [K] int32, sorted by (tile, depth, gid)
    emit_from_isect: np.ndarray  # [K] int32, the emit slot of each sorted intersection
    tile_ranges: np.ndarray  # [T, 2] int32 [start, end) into the sorted list


@dataclass
class RasterOut:
    """Output of `rasterize_fwd` (per pixel)."""

    rgb: np.ndarray  # [H, W, 3]
    depth: np.ndarray  # [H, W]
    alpha: np.ndarray  # [H, W]
    final_T: np.ndarray  # [H, W]
    last: np.ndarray  # [H, W] int32: 1 + position, within its tile's list, of the pixel's last blended Gaussian (0: none)
    importance: np.ndarray | None = None  # [N] sum of alpha*T over blended pixels, if asked


@dataclass
class RasterGrads:
    """Output of `rasterize_bwd` after `isect_reduce`: cotangents of the projected quantities."""

    v_means2d: np.ndarray  # [N, 2]
    v_conics: np.ndarray  # [N, 3]
    v_colors: np.ndarray  # [N, 3]
    v_opacities: np.ndarray  # [N] dL/d(effective opacity)
    v_depths: np.ndarray  # [N] dL/d(t_z) through the depth image


class Backend(Protocol):
    """What `reings.render` needs from a device. Stage methods take and return host numpy arrays
    (for tests); `render` / `render_vjp` are the fused fast path."""

    name: str

    def render(self, gaussians: Gaussians, camera: Camera, background: Sequence[float] = (0, 0, 0),
               near: float = 0.01, opacity_override: float | None = None,
               want_importance: bool = False) -> RenderOutput: ...

    def render_vjp(self, gaussians: Gaussians, camera: Camera, v_rgb: np.ndarray,
                   v_depth: np.ndarray | None = None, v_alpha: np.ndarray | None = None,
                   background: Sequence[float] = (0, 0, 0), near: float = 0.01,
                   opacity_override: float | None = None,
                   grad_fields: Sequence[str] | None = None) -> Gaussians: ...
