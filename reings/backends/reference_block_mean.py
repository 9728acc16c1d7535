"""Float64 twin of the block mean (`block_mean`, kernels/block_mean.cl) and its adjoint, and the
float32 mirror of the kernels' operations.

An image a [H, W, ...] pools to [Ho, Wo, ...], Ho = H // s, Wo = W // s: pixel (i, j) is the mean of
a's pixels [s i, s i + s) x [s j, s j + s), the last rows and columns that do not fill a block dropped
(the pixels of reings.train.depth_pass_camera's camera at 1/s). The map is linear, A; its adjoint A^T
gives every pixel of block (i, j) the value v(i, j) / s^2 and the dropped pixels 0, so that
<A x, y> = <x, A^T y> (tests/test_block_mean.py).

    block_mean_fwd(a, s)              A a, float64
    block_mean_bwd(v, s, shape)       A^T v, float64, of the full-resolution `shape`
    block_mean(a, s)                  block_mean_fwd rounded to float32, contiguous: the pooled depth
                                      prior and its weights of the hard depth pass at 1/s
                                      (LossConfig.hard_depth_scale), the views of a fit at 1/s
                                      (reings.train.block_mean is this function)
    block_mean_f32(a, s)              the kernels' float32 operations in their order (the s^2 values of a
    block_mean_bwd_f32(v, s, shape)   block summed row by row, left to right, from 0; times float32(1 / s^2);
                                      the adjoint v * float32(1 / s^2), written or added into `into`): the
                                      host trainer's, so that on PoCL both trainers give the same bits

Users: the view_warp term at 1/s (LossConfig.view_warp_scale, docs/binocular.md §4.5) pools the
training render's depth and the training image with A and spreads its depth cotangent back with A^T.
"""
from __future__ import annotations

import numpy as np

_F32 = np.float32


def block_sizes(shape, scale) -> tuple[int, int, int]:
    """(Ho, Wo, s) of an image of `shape` pooled over s x s blocks; s an integer >= 1."""
    s = int(scale)
    if s != scale or s < 1:
        raise ValueError(f"block_mean: the scale must be an integer >= 1, got {scale!r}")
    if len(shape) < 2:
        raise ValueError(f"block_mean: an image [H, W, ...], got shape {tuple(shape)}")
    return shape[0] // s, shape[1] // s, s


def _check_adjoint_shapes(v_shape, scale, shape) -> tuple[int, int, int]:
    ho, wo, s = block_sizes(shape, scale)
    if tuple(v_shape) != (ho, wo) + tuple(shape[2:]):
        raise ValueError(f"block_mean_bwd: a cotangent of shape {(ho, wo) + tuple(shape[2:])} for a {tuple(shape)} "
                         f"image at scale {s}, got {tuple(v_shape)}")
    return ho, wo, s


def block_mean_fwd(a, scale: int) -> np.ndarray:
    """[H, W, ...] -> [H // s, W // s, ...] float64: the mean of each s x s block (module docstring)."""
    a = np.asarray(a)
    h, w, s = block_sizes(a.shape, scale)
    b = a[:h * s, :w * s].astype(np.float64).reshape(h, s, w, s, *a.shape[2:])
    return b.mean(axis=(1, 3))


def block_mean_bwd(v, scale: int, shape) -> np.ndarray:
    """The adjoint of block_mean_fwd: [Ho, Wo, ...] -> `shape` [H, W, ...] float64, v(i, j) / s^2 on every
    pixel of block (i, j), 0 on the rows and columns block_mean_fwd dropped."""
    v = np.asarray(v, np.float64)
    ho, wo, s = _check_adjoint_shapes(v.shape, scale, shape)
    out = np.zeros(tuple(shape), np.float64)
    out[:ho * s, :wo * s] = np.repeat(np.repeat(v, s, axis=0), s, axis=1) / (s * s)
    return out


def block_mean(a, scale: int) -> np.ndarray:
    """[H, W, ...] -> [H // s, W // s, ...] float32: block_mean_fwd (summed in float64) rounded, contiguous."""
    return np.ascontiguousarray(block_mean_fwd(a, scale), dtype=_F32)


def block_mean_inv(scale: int) -> np.float32:
    """float32(1 / s^2), the kernels' factor (exact for s = 1, 2, 4)."""
    return _F32(1.0 / (int(scale) * int(scale)))


def block_mean_f32(a, scale: int) -> np.ndarray:
    """kernels/block_mean.cl block_mean_fwd's float32 operations in its order: per output element the
    block's values added row by row, left to right, to 0.0f, then times block_mean_inv(s)."""
    a = np.asarray(a, _F32)
    ho, wo, s = block_sizes(a.shape, scale)
    acc = np.zeros((ho, wo) + a.shape[2:], _F32)
    for dy in range(s):
        for dx in range(s):
            acc += a[dy:ho * s:s, dx:wo * s:s]
    return acc * block_mean_inv(s)


def block_mean_bwd_f32(v, scale: int, shape, into: np.ndarray | None = None) -> np.ndarray:
    """kernels/block_mean.cl block_mean_bwd's float32 operations: v * block_mean_inv(s) on every pixel of
    its block, 0 on the dropped ones; a new array, or added into `into` (float32, `shape`; returned)."""
    v = np.asarray(v, _F32)
    ho, wo, s = _check_adjoint_shapes(v.shape, scale, shape)
    g = np.zeros(tuple(shape), _F32)
    g[:ho * s, :wo * s] = np.repeat(np.repeat(v * block_mean_inv(s), s, axis=0), s, axis=1)
    if into is None:
        return g
    if into.shape != tuple(shape) or into.dtype != _F32:
        raise ValueError(f"block_mean_bwd: into must be float32 {tuple(shape)}, got {into.dtype} {into.shape}")
    into += g
    return into
