"""Float64 reference of the binocular view-consistency term (`view_warp`), its hand-derived
backward, the virtual camera it needs, and the opacity-decay rule of the same paper.

Han et al., "Binocular-Guided 3D Gaussian Splatting with View Consistency for Sparse View
Synthesis" (NeurIPS 2024, arXiv 2410.18822); what follows is read from the authors' public code
(hanl2010/Binocular3DGS, docs/binocular.md cites file and line for every rule).

    virtual_camera(camera, baseline)  the training camera moved by `baseline` along its own x axis
                                      (world-to-camera translation t' = t - baseline * e_x; same
                                      rotation, intrinsics and size)
    draw_baseline(rng, max_baseline)  |b| ~ U[0, max_baseline), then a random sign (the authors'
                                      draw order)
    view_warp_fwd / view_warp_bwd / view_warp_fwd_bwd
                                      the loss below and its gradients w.r.t. the virtual render
                                      and the training view's rendered depth
    opacity_decay(logits, factor)     logit(factor * sigmoid(logit)), stable for any logit

The term, for a training view with image `gt` [H, W, 3], rendered depth D [H, W] (sum of
t_z * alpha * T, not normalised by alpha: the depth of both reings' rasterizer and the authors'),
focal fx, and the image `virt` [H, W, 3] rendered from virtual_camera(camera, b):

    d(y, x)   = -fx b / (D(y, x) + 1e-5)                        disparity, pixels (DEPTH_EPS)
    x0        = floor(d), w1 = d - x0, w0 = (x0 + 1) - d,  c0 = x + x0
    valid     = 0 <= c0 <= W - 2  (both taps inside the row)   (also: D finite, |d| < W + 1, which
                                                                 only removes off-image taps)
    warped_c  = w0 virt_c(y, c0) + w1 virt_c(y, c0 + 1)  where valid, else 0
    L1        = sum over valid pixels and channels |warped_c - gt_c| / (3 H W)   (the mean over ALL
                3HW elements, invalid ones counting as 0: the authors' masked mean)
    p         = valid ? d : 0                                   (the authors' disparity * mask)
    smooth    = [sum_o wx(o) |ex(o)| + sum_o wy(o) |ey(o)|] / ((H - 2)(W - 2)), o over the interior
                pixels 1 <= y <= H-2, 1 <= x <= W-2, with central differences
                ex(o) = (p(y, x+1) - p(y, x-1)) / 2,   ey(o) = (p(y+1, x) - p(y-1, x)) / 2
                wx(o) = exp(-0.33 |(S(y, x+1) - S(y, x-1)) / 2|), S = gt summed over channels (wy alike)
    loss      = weight * (L1 + smooth_weight * smooth)          (authors: weight 1, smooth_weight 0.05)

Gradients (nothing is detached in the authors' graph; floor and the validity test are piecewise
constant, the mask's own derivative is (-1) + (+1) = 0):
    dL/dvirt_c(y, c0)     += w0 g_c,   dL/dvirt_c(y, c0 + 1) += w1 g_c,   g_c = weight sign(r_c) / (3HW)
    dL/dd(y, x)            = sum_c g_c (virt_c(y, c0 + 1) - virt_c(y, c0))
                             + weight smooth_weight / Ns * (sx(y, x-1) - sx(y, x+1) + sy(y-1, x) - sy(y+1, x)) / 2
                           with sx(o) = wx(o) sign(ex(o)) (0 off the interior), sy alike
    dL/dD(y, x)            = valid ? dL/dd * (-d / (D + 1e-5)) : 0
sign(0) = 0 (torch's abs gradient at 0).

Deviations from the authors' float32 torch code, each deliberate:
  - the mask is exactly 1 on valid pixels (theirs is (x1 - d) + (d - x0) in float32: 1 up to one
    rounding, and only the value, never the gradient, differs);
  - a non-finite depth makes its pixel invalid (theirs: NaN propagates into the whole loss);
  - H < 3 or W < 3: smooth = 0 (theirs: the mean of an empty convolution, NaN).
`kernels/view_warp.cl` must match this module (tests/test_view_warp.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Camera

DEPTH_EPS = 1e-5  # disparity = f b / (depth + 1e-5) (authors' train.py)
EDGE_SCALE = 0.33  # image-edge weight exp(-0.33 |dI|) of the disparity smoothness (authors' SmoothLoss)
MAX_BASELINE = 0.4  # authors' --cam_trans_dist (world units of the 3DGS COLMAP frame)
SMOOTH_WEIGHT = 0.05  # authors' weight of the smoothness inside the term
OPACITY_DECAY = 0.995  # authors' --opacity_decay_factor (applied every iteration after densify_from)


# {{{ cameras


def virtual_camera(camera: Camera, baseline: float) -> Camera:
    """The binocular partner of `camera`: its centre moved by `baseline` along the camera's own x
    axis (world position C + baseline * R[0, :]), same rotation and intrinsics. In camera
    coordinates a point (X, Y, Z) of the training camera is (X - baseline, Y, Z) in the virtual
    one, so a pixel at depth Z moves by -fx * baseline / Z: the virtual image sampled at
    x - fx b / Z (i.e. at x + disparity) reproduces the training view."""
    b = float(baseline)
    if not np.isfinite(b):
        raise ValueError(f"virtual_camera: baseline must be finite, got {baseline!r}")
    V = np.array(camera.viewmat, dtype=np.float64)  # [4, 4] world-to-camera
    V[0, 3] -= b  # t' = t - b e_x  <=>  C' = -R^T t' = C + b R^T e_x
    return Camera(K=np.array(camera.K, dtype=np.float64), viewmat=V, width=camera.width, height=camera.height)


def draw_baseline(rng: np.random.Generator, max_baseline: float = MAX_BASELINE) -> float:
    """A signed baseline: magnitude uniform in [0, max_baseline), then the sign by a fair coin
    (the authors' `torch.rand(1) * cam_trans_dist * random.choice([-1, 1])`, same order of draws:
    two draws per call, whatever max_baseline is)."""
    mag = float(rng.random()) * float(max_baseline)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    return sign * mag
# }}}


# {{{ the term


@dataclass
class WarpState:
    """Every intermediate of the forward pass (float64, [H, W] unless said)."""

    d: np.ndarray  # disparity (NaN / inf kept where the depth makes it so)
    valid: np.ndarray  # bool
    x0: np.ndarray  # int64 floor(d) (0 where not valid)
    c0: np.ndarray  # int64 left tap column (0 where not valid)
    w0: np.ndarray  # left tap weight (0 where not valid)
    w1: np.ndarray  # right tap weight (0 where not valid)
    tap0: np.ndarray  # [H, W, 3] virt at the left tap (0 where not valid)
    tap1: np.ndarray  # [H, W, 3] virt at the right tap (0 where not valid)
    warped: np.ndarray  # [H, W, 3] (0 where not valid)
    r: np.ndarray  # [H, W, 3] warped - gt where valid, else 0
    p: np.ndarray  # valid ? d : 0
    ex: np.ndarray  # [H-2, W-2] (empty if H < 3 or W < 3)
    ey: np.ndarray
    wx: np.ndarray
    wy: np.ndarray


def neg_fb(fx: float, baseline: float) -> float:
    """The numerator of the disparity, -fx * baseline (float64; kernels receive it as float32)."""
    return -float(fx) * float(baseline)


def view_warp_state(virt: np.ndarray, depth: np.ndarray, gt: np.ndarray, fx: float, baseline: float) -> WarpState:
    """The forward intermediates (module docstring)."""
    virt = np.asarray(virt, np.float64)
    D = np.asarray(depth, np.float64)
    gt = np.asarray(gt, np.float64)
    if D.ndim != 2 or virt.shape != D.shape + (3,) or gt.shape != virt.shape:
        raise ValueError(f"view_warp: virt, gt [H, W, 3] and depth [H, W], got {virt.shape}, {gt.shape}, {D.shape}")
    h, w = D.shape
    with np.errstate(all="ignore"):  # depth -1e-5 / NaN / inf: non-finite disparities, masked below
        d = neg_fb(fx, baseline) / (D + DEPTH_EPS)
        ok = np.isfinite(D) & (np.abs(d) < w + 1)  # NaN fails; |d| >= W + 1 never lands inside anyway
    x0 = np.floor(np.where(ok, d, 0.0)).astype(np.int64)
    c0 = np.arange(w)[None, :] + x0
    valid = ok & (c0 >= 0) & (c0 + 1 < w)
    x0 = np.where(valid, x0, 0)
    c0 = np.where(valid, c0, 0)
    w1 = np.where(valid, np.where(valid, d, 0.0) - x0, 0.0)
    w0 = np.where(valid, (x0 + 1) - np.where(valid, d, 0.0), 0.0)
    rows = np.arange(h)[:, None]
    tap0 = np.where(valid[..., None], virt[rows, c0], 0.0)
    tap1 = np.where(valid[..., None], virt[rows, np.minimum(c0 + 1, w - 1)], 0.0)
    warped = w0[..., None] * tap0 + w1[..., None] * tap1
    r = np.where(valid[..., None], warped - gt, 0.0)
    p = np.where(valid, d, 0.0)
    if h > 2 and w > 2:
        s = gt.sum(axis=2)
        ex = 0.5 * (p[1:-1, 2:] - p[1:-1, :-2])
        ey = 0.5 * (p[2:, 1:-1] - p[:-2, 1:-1])
        wx = np.exp(-EDGE_SCALE * np.abs(0.5 * (s[1:-1, 2:] - s[1:-1, :-2])))
        wy = np.exp(-EDGE_SCALE * np.abs(0.5 * (s[2:, 1:-1] - s[:-2, 1:-1])))
    else:
        ex = ey = wx = wy = np.zeros((max(h - 2, 0), max(w - 2, 0)))
    return WarpState(d=d, valid=valid, x0=x0, c0=c0, w0=w0, w1=w1, tap0=tap0, tap1=tap1, warped=warped, r=r,
                     p=p, ex=ex, ey=ey, wx=wx, wy=wy)


def _terms(st: WarpState) -> tuple[float, float]:
    """(sum |r|, sum of the smoothness terms) of a state."""
    return float(np.abs(st.r).sum()), float((st.wx * np.abs(st.ex)).sum() + (st.wy * np.abs(st.ey)).sum())


def term_weights(h: int, w: int, weight: float, smooth_weight: float) -> tuple[float, float]:
    """(dL/d|r| per element, dL/d(one smoothness term)) = (weight / 3HW, weight * smooth_weight / Ns);
    the second is 0 when the image has no interior pixel."""
    gl = float(weight) / (3.0 * h * w)
    ns = (h - 2) * (w - 2)
    gs = float(weight) * float(smooth_weight) / ns if h > 2 and w > 2 else 0.0
    return gl, gs


def view_warp_fwd(virt, depth, gt, fx: float, baseline: float, weight: float = 1.0,
                  smooth_weight: float = SMOOTH_WEIGHT) -> tuple[float, np.ndarray, np.ndarray]:
    """(loss, warped [H, W, 3], valid [H, W] bool)."""
    st = view_warp_state(virt, depth, gt, fx, baseline)
    h, w = st.d.shape
    gl, gs = term_weights(h, w, weight, smooth_weight)
    l1, sm = _terms(st)
    return gl * l1 + gs * sm, st.warped, st.valid


def view_warp_stats(virt, depth, gt, fx: float, baseline: float) -> dict:
    """The unweighted sums the kernels report: l1_sum (sum |r|), smooth_sum, valid (count)."""
    st = view_warp_state(virt, depth, gt, fx, baseline)
    l1, sm = _terms(st)
    return {"l1_sum": l1, "smooth_sum": sm, "valid": int(st.valid.sum())}


def view_warp_bwd(virt, depth, gt, fx: float, baseline: float, weight: float = 1.0,
                  smooth_weight: float = SMOOTH_WEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """(v_virt [H, W, 3], v_depth [H, W]) = dL/dvirt, dL/ddepth (module docstring)."""
    st = view_warp_state(virt, depth, gt, fx, baseline)
    D = np.asarray(depth, np.float64)
    h, w = D.shape
    gl, gs = term_weights(h, w, weight, smooth_weight)
    g = gl * np.sign(st.r)  # [H, W, 3], 0 where not valid (r = 0 there)
    v_virt = np.zeros((h, w, 3))
    ys, xs = np.nonzero(st.valid)
    c0 = st.c0[ys, xs]
    np.add.at(v_virt, (ys, c0), st.w0[ys, xs, None] * g[ys, xs])
    np.add.at(v_virt, (ys, c0 + 1), st.w1[ys, xs, None] * g[ys, xs])
    gd = (g * (st.tap1 - st.tap0)).sum(axis=2)  # dL/dd through the bilinear weights
    if gs != 0.0:
        sx = np.zeros((h + 2, w + 2))  # sx(o) at [y + 1, x + 1], zero off the interior and outside
        sy = np.zeros((h + 2, w + 2))
        sx[2:-2, 2:-2] = st.wx * np.sign(st.ex)
        sy[2:-2, 2:-2] = st.wy * np.sign(st.ey)
        # dS/dp(y, x) = (sx(y, x-1) - sx(y, x+1) + sy(y-1, x) - sy(y+1, x)) / 2
        dp = 0.5 * (sx[1:-1, :-2] - sx[1:-1, 2:] + sy[:-2, 1:-1] - sy[2:, 1:-1])
        gd = gd + gs * dp
    with np.errstate(all="ignore"):
        dd_dD = -st.d / (D + DEPTH_EPS)
    v_depth = np.where(st.valid, gd * np.where(st.valid, dd_dD, 0.0), 0.0)
    return v_virt, v_depth


def view_warp_fwd_bwd(virt, depth, gt, fx: float, baseline: float, weight: float = 1.0,
                      smooth_weight: float = SMOOTH_WEIGHT) -> tuple[float, np.ndarray, np.ndarray]:
    """(loss, v_virt, v_depth)."""
    loss = view_warp_fwd(virt, depth, gt, fx, baseline, weight, smooth_weight)[0]
    return (loss,) + view_warp_bwd(virt, depth, gt, fx, baseline, weight, smooth_weight)


def view_warp_pattern(virt, depth, gt, fx: float, baseline: float) -> np.ndarray:
    """Every discrete decision of the forward pass (validity, floor(d), the signs of r, ex and ey)
    as one int array: the loss is smooth in the inputs wherever this does not change, so a central
    difference whose two ends share a pattern measures the analytic gradient (tests)."""
    st = view_warp_state(virt, depth, gt, fx, baseline)
    return np.concatenate([st.valid.ravel().astype(np.int64), st.x0.ravel(), np.sign(st.r).ravel().astype(np.int64),
                           np.sign(st.ex).ravel().astype(np.int64), np.sign(st.ey).ravel().astype(np.int64)])
# }}}


# {{{ opacity decay


def opacity_decay(opacity_logits: np.ndarray, factor: float = OPACITY_DECAY) -> np.ndarray:
    """The logits of factor * sigmoid(logits), float64 (the authors' `opacity_decay`: opacity
    scaled by `factor`, written back through the inverse sigmoid). Closed form
        logit(f s(x)) = log f - log((1 - f) + exp(-x)) = log f - logaddexp(log(1 - f), -x)
    finite for every finite x (the float32 round trip through the opacity underflows to -inf below
    x ~ -88, or ~ -103 with denormals, and loses precision near s(x) = 1). factor in (0, 1]; factor 1 is the identity."""
    f = float(factor)
    if not 0.0 < f <= 1.0:
        raise ValueError(f"opacity_decay: factor must lie in (0, 1], got {factor!r}")
    x = np.asarray(opacity_logits, np.float64)
    if f == 1.0:
        return x.copy()
    return np.log(f) - np.logaddexp(np.log1p(-f), -x)
# }}}
