"""Training losses on host arrays, each returning (loss, dL/d input), on any device: they resolve
the backend (`reings.backends.get_backend`) and call its host loss method, so this module holds no
kernel code (the OpenCL host code is reings/backends/opencl/losses.py, the float64 references
reings/backends/reference_loss.py).

    photometric_loss(rgb, gt, lambda_dssim, form, device)  -> (loss, v_rgb [H,W,3])
        L1 + SSIM of 3DGS (Backend.photometric_loss).
    depth_loss(depth, target, rng, patch_range, margin, w_local, w_global, device, smooth) -> (loss, v_depth [H,W])
        DNGaussian's global-local depth normalisation (docs/method.md §2.4), a random patch size per term
        (drawn on the host: `draw_depth_patches`), plus the optional depth_smooth term
        (Backend.depth_loss; device None: the float64 reference).
    regularizers(params, shape_pena, scale_pena, opa_pena) -> (loss, {"log_scales": .., "opacity_logits": ..})
        DNGaussian's shape / scale / opacity penalties (docs/method.md §2.2) on the raw parameters: the
        regularize stage's float64 twin, reference_loss.regularize_fwd_bwd.

The training engine (reings/train.py) runs the same losses through its Trainer
(reings/backends/base.py): hard depth = depth loss on a render with opacity_override=0.95, its
v_depth into the backward of the means only, Adam step of "means"; soft depth = the same on the
normal render for the opacities; then photometric + regularizers, step of every group
(DNGaussian, docs/method.md §2.3-2.4).
"""
from __future__ import annotations

import numpy as np

from .backends import get_backend
from .backends.reference_loss import (DepthSmoothWeights, opacity_reg, photometric_weights,  # noqa: F401 (re-export)
                                      regularize_fwd_bwd, scale_reg, shape_reg)

__all__ = ["photometric_loss", "photometric_weights", "depth_loss", "draw_depth_patches", "DepthSmoothWeights",
           "regularizers", "shape_reg", "scale_reg", "opacity_reg"]


def photometric_loss(rgb: np.ndarray, gt: np.ndarray, lambda_dssim: float = 0.2, form: str = "dngaussian",
                     device: str = "pocl") -> tuple[float, np.ndarray]:
    """(loss, dL/d rgb float32) of the photometric loss for images [H, W, 3] on `device`.

    form "dngaussian": L1 + lambda * (1 - SSIM)   (DNGaussian train_llff.py)
    form "3dgs":       (1 - lambda) * L1 + lambda * (1 - SSIM)   (3DGS train.py)
    """
    w_l1, w_ssim = photometric_weights(lambda_dssim, form)
    rgb = np.asarray(rgb)
    gt = np.asarray(gt)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape != gt.shape:
        raise ValueError(f"rgb and gt must be [H, W, 3] of one shape, got {rgb.shape} and {gt.shape}")
    return get_backend(device).photometric_loss(rgb, gt, w_l1, w_ssim)


def draw_depth_patches(rng: np.random.Generator, patch_range: tuple[int, int], h: int, w: int) -> tuple[int, int]:
    """The two patch sizes of one depth-loss call: uniform in [lo, hi] inclusive, local first (as
    DNGaussian draws them), each clamped to min(h, w). The fit loop and `depth_loss` draw through
    this."""
    lo, hi = int(patch_range[0]), int(patch_range[1])
    cap = min(int(h), int(w))
    p_local = min(int(rng.integers(lo, hi + 1)), cap)
    p_global = min(int(rng.integers(lo, hi + 1)), cap)
    return p_local, p_global


def depth_loss(depth: np.ndarray, target: np.ndarray, rng: np.random.Generator,
               patch_range: tuple[int, int] = (5, 17), margin: float = 0.00025,
               w_local: float = 0.1, w_global: float = 1.0, device: str | None = None,
               smooth: tuple | None = None, weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """DNGaussian's depth loss on a rendered depth [H, W] against the (constant) mono target:
    w_local * local + w_global * global, each term with its own patch size drawn uniformly from
    [lo, hi] inclusive (local first, as DNGaussian draws them; clamped to the image size).
    Returns (loss, v_depth float32 [H, W]).  What is detached: see
    `reference_loss.depth_norm_loss_fwd_bwd`.

    `smooth`: None, or (DepthSmoothWeights of this target, w_smooth) to add w_smooth times the
    depth_smooth term, DNGaussian's edge-aware smoothness (`reference_loss.depth_smooth_fwd_bwd`;
    LLFF after iteration 3000). `weight`: None, or [H, W] per-pixel weights in [0, 1] on each
    selected element's squared error (`reference_loss.depth_confidence_weights` of a prior's
    confidence; LossConfig.depth_confidence).

    device None: the float64 numpy reference (device "reference"); else that device's
    Backend.depth_loss (OpenCL: kernels/depth_loss.cl, host arrays uploaded, v_depth read back)."""
    h, w = np.shape(depth)[:2]
    p_local, p_global = draw_depth_patches(rng, patch_range, h, w)
    backend = get_backend("reference" if device is None else device)
    return backend.depth_loss(depth, target, p_local, p_global, margin, w_local, w_global, smooth, weight)


def regularizers(params: dict, shape_pena: float = 0.0, scale_pena: float = 0.0,
                 opa_pena: float = 0.0) -> tuple[float, dict[str, np.ndarray]]:
    """shape_pena * shape + scale_pena * scale + opa_pena * opacity (DNGaussian, added to the
    photometric loss) on host parameters; gradients (float32) only for the fields with a non-zero
    weight. The regularize stage's float64 twin (reference_loss.regularize_fwd_bwd), which the
    host trainer runs and kernels/regularize.cl matches."""
    return regularize_fwd_bwd(params, shape_pena, scale_pena, opa_pena)
