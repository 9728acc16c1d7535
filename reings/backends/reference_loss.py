"""Float64 numpy references of the training losses, each returning (loss, dL/d input).

    ssim_fwd_bwd            mean SSIM of 3DGS (`utils/loss_utils.py` ssim): Gaussian window 11,
                            sigma 1.5, zero-padded 'same' convolution per channel, C1 = 0.01^2,
                            C2 = 0.03^2, mean over the whole map; gradient w.r.t. the first image
    l1_fwd_bwd              mean |x - y| (gradient sign(x - y), 0 at ties, as torch)
    photometric_fwd_bwd     "dngaussian": L1 + l*(1 - SSIM);  "3dgs": (1 - l)*L1 + l*(1 - SSIM)
    depth_norm_loss_fwd_bwd one term of DNGaussian's global-local depth normalisation
                            (`utils/loss_utils.py` patch_norm_mse_loss[_global], docs/method.md §2.4)
    global_local_depth_loss w_local * local(p1) + w_global * global(p2)
    depth_smooth_fwd_bwd    the depth_smooth stage: DNGaussian's LLFF edge-aware depth smoothness
                            (`loss_depth_smoothness`), weights from the target
                            (depth_smooth_weights, DepthSmoothWeights)
    regularize_fwd_bwd      the regularize stage: DNGaussian's shape / scale / opacity penalties
                            on the raw parameters (shape_reg, scale_reg, opacity_reg)
    depth_metric_fwd_bwd    the depth_metric stage: relative L1 of the rendered depth against the
                            prior's metric depth, weighted by its confidence (docs/method.md §10)

Values the loop only logs (no gradient): `mse_rows` / `mse` (the train PSNR's mean squared error,
kernels/mse.cl, tests/test_mse.py) and `regularize_value` (the penalties' value from per-chunk sums,
kernels/regularize.cl regularize_value, tests/test_adam_kernel.py).

`kernels/photometric.cl` and `kernels/l1.cl` must match the first three (tests/test_losses.py,
tests/test_peer_step.py), `kernels/depth_loss.cl` the depth terms (tests/test_depth_loss_kernel.py),
`kernels/regularize.cl` the penalties (tests/test_adam_kernel.py), `kernels/depth_metric.cl` the
metric depth term (tests/test_depth_metric.py).

`photometric_loss` and `depth_loss` are the reference backend's host loss methods (the Backend
protocol, reings/backends/base.py): on device "reference" they are the losses themselves.
"""
from __future__ import annotations

import numpy as np

SSIM_WINDOW = 11  # 3DGS window size
SSIM_SIGMA = 1.5  # 3DGS window sigma
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def gaussian_taps(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The normalised 1-D Gaussian of 3DGS `gaussian(window_size, sigma)`; the 2-D window is its
    outer product, so the 2-D convolution is a horizontal then a vertical pass."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x ** 2) / (2.0 * sigma ** 2))
    return g / g.sum()


def conv_same(img: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Zero-padded 'same' separable convolution of [H, W, ...] over H and W. With symmetric taps
    this operator is self-adjoint, so the backward pass reuses it."""
    r = len(taps) // 2
    h, w = img.shape[:2]
    pad = [(r, r), (0, 0)] + [(0, 0)] * (img.ndim - 2)
    p = np.pad(img, pad)
    tmp = sum(taps[k] * p[k:k + h] for k in range(len(taps)))  # vertical
    pad = [(0, 0), (r, r)] + [(0, 0)] * (img.ndim - 2)
    p = np.pad(tmp, pad)
    return sum(taps[k] * p[:, k:k + w] for k in range(len(taps)))  # horizontal


def ssim_map_and_partials(x: np.ndarray, y: np.ndarray):
    """SSIM map S [H,W,C] and its partials w.r.t. (mu_x, E[x^2], E[xy]) at each pixel."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    g = gaussian_taps()
    mx, my = conv_same(x, g), conv_same(y, g)
    exx, eyy, exy = conv_same(x * x, g), conv_same(y * y, g), conv_same(x * y, g)
    sx, sy, sxy = exx - mx * mx, eyy - my * my, exy - mx * my
    a1, a2 = 2 * mx * my + SSIM_C1, 2 * sxy + SSIM_C2
    b1, b2 = mx * mx + my * my + SSIM_C1, sx + sy + SSIM_C2
    d = b1 * b2
    s = a1 * a2 / d
    ds_dmx = (2 * my * (a2 - a1) - s * 2 * mx * (b2 - b1)) / d
    ds_dexx = -s * b1 / d
    ds_dexy = 2 * a1 / d
    return s, ds_dmx, ds_dexx, ds_dexy


def ssim_fwd_bwd(x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean SSIM(x, y), d mean SSIM / dx), x and y [H, W, C]."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    s, dmx, dexx, dexy = ssim_map_and_partials(x, y)
    w = 1.0 / s.size
    g = gaussian_taps()
    # mu_x = G*x, E[x^2] = G*(x^2), E[xy] = G*(x y); G is self-adjoint
    v = conv_same(dmx * w, g) + 2 * x * conv_same(dexx * w, g) + y * conv_same(dexy * w, g)
    return float(s.mean()), v


def l1_fwd_bwd(x: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    d = np.asarray(x, np.float64) - np.asarray(y, np.float64)
    return float(np.abs(d).mean()), np.sign(d) / d.size


def photometric_weights(lambda_dssim: float, form: str) -> tuple[float, float]:
    """(weight of L1, weight of (1 - SSIM))."""
    if form == "dngaussian":
        return 1.0, float(lambda_dssim)
    if form == "3dgs":
        return 1.0 - float(lambda_dssim), float(lambda_dssim)
    raise ValueError(f"photometric form must be 'dngaussian' or '3dgs', got {form!r}")


def photometric_fwd_bwd(x, y, lambda_dssim: float = 0.2, form: str = "dngaussian") -> tuple[float, np.ndarray]:
    """(w_l1 * L1 + w_ssim * (1 - SSIM), its gradient w.r.t. x), weights from `photometric_weights`."""
    return weighted_photometric_fwd_bwd(x, y, *photometric_weights(lambda_dssim, form))


def weighted_photometric_fwd_bwd(x, y, w_l1: float, w_ssim: float) -> tuple[float, np.ndarray]:
    """w_l1 * L1 + w_ssim * (1 - SSIM) of [H,W,C] images and its float64 gradient w.r.t. x."""
    l1, vl1 = l1_fwd_bwd(x, y)
    s, vs = ssim_fwd_bwd(x, y)
    return w_l1 * l1 + w_ssim * (1.0 - s), w_l1 * vl1 - w_ssim * vs


def photometric_loss(rgb: np.ndarray, gt: np.ndarray, w_l1: float, w_ssim: float) -> tuple[float, np.ndarray]:
    """The reference backend's photometric loss: (loss, float32 dL/d rgb) of [H,W,3] images."""
    loss, v = weighted_photometric_fwd_bwd(rgb, gt, w_l1, w_ssim)
    return loss, v.astype(np.float32)


# {{{ depth: DNGaussian global-local normalisation
def patchify(img: np.ndarray, p: int) -> np.ndarray:
    """[H, W] -> [M, p*p] non-overlapping p x p patches, stride p, leftovers dropped
    (torch `F.unfold(kernel=p, stride=p)`, patches row-major, pixels row-major inside)."""
    h, w = img.shape
    ph, pw = h // p, w // p
    if ph == 0 or pw == 0:
        raise ValueError(f"patch size {p} is larger than the image {h}x{w}")
    return img[: ph * p, : pw * p].reshape(ph, p, pw, p).transpose(0, 2, 1, 3).reshape(ph * pw, p * p)


def unpatchify(v: np.ndarray, p: int, shape) -> np.ndarray:
    """Adjoint of `patchify`: [M, p*p] back to [H, W], zeros in the dropped leftovers."""
    h, w = shape
    ph, pw = h // p, w // p
    out = np.zeros(shape, v.dtype)
    out[: ph * p, : pw * p] = v.reshape(ph, pw, p, p).transpose(0, 2, 1, 3).reshape(ph * p, pw * p)
    return out


def _normalize_fwd(P: np.ndarray, image_std: float | None):
    """DNGaussian `normalize`: (P - patch mean) / (scale + 0.01 * std(all patch values)), scale =
    per-patch unbiased std (local) or the given detached whole-image std (global)."""
    n = P.shape[1]
    u = P - P.mean(axis=1, keepdims=True)
    s_all = P.std(ddof=1)
    s_patch = u.std(axis=1, ddof=1, keepdims=True) if image_std is None else None
    d = (s_patch if image_std is None else image_std) + 0.01 * s_all
    return u / d, (u, d, s_patch, s_all, n)


def _normalize_bwd(g: np.ndarray, P: np.ndarray, cache, local: bool) -> np.ndarray:
    u, d, s_patch, s_all, n = cache
    gu = g / d  # through the numerator
    gd = -(g * u).sum(axis=1, keepdims=True) / (d * d)  # [M, 1]
    if local:  # d = s_patch + 0.01 s_all; ds_patch/dP = u / ((n-1) s_patch) (0 where s_patch = 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.where(s_patch > 0, gd / ((n - 1) * s_patch), 0.0)
        gu = gu + coef * u
    # 0.01 * s_all, s_all over every patch value (not detached in DNGaussian)
    gs_all = 0.01 * gd.sum()
    if s_all > 0:
        mean_all = P.mean()
        g_all = gs_all * (P - mean_all) / ((P.size - 1) * s_all)
    else:
        g_all = 0.0
    # the patch mean: u = P - mean(P) per patch
    gP = gu - gu.mean(axis=1, keepdims=True)
    return gP + g_all


def depth_norm_loss_fwd_bwd(depth: np.ndarray, target: np.ndarray, patch: int, margin: float,
                            mode: str = "local", image_std: float | None = None,
                            weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """One DNGaussian depth term and its gradient w.r.t. the rendered `depth` [H, W].

    mode "local":  patch_norm_mse_loss        (per-patch std)
    mode "global": patch_norm_mse_loss_global (whole-image std of each input, detached)
    Loss = mean of (x_hat - y_hat)^2 over elements with |x_hat - y_hat| > margin.

    Detached exactly as in DNGaussian: the target (mono depth) is constant; in "global" the
    whole-image std is detached; the margin mask and the count of selected elements are piecewise
    constant (no gradient).  `image_std` overrides the detached whole-image std of `depth` (for
    finite-difference tests, which must hold detached quantities fixed).  NOT detached: the patch means, the per-patch stds and the 0.01 * std of
    all patch values.  Deviations: an empty mask gives loss 0 (torch: NaN) and a zero per-patch std
    gives that term zero gradient (torch: NaN).

    `weight` (proposal, not DNGaussian's): None, or [H, W] per-pixel weights w in [0, 1] (the
    stereo prior's confidence, `depth_confidence_weights`) on each selected element's squared
    error: loss = sum over the mask of w (x_hat - y_hat)^2 / cnt, cnt still the number of selected
    elements; the normalisation statistics stay unweighted. All-ones weights give the unweighted loss.
    """
    if mode not in ("local", "global"):
        raise ValueError(f"mode must be 'local' or 'global', got {mode!r}")
    depth = np.asarray(depth, np.float64)
    target = np.asarray(target, np.float64)
    if depth.ndim != 2 or depth.shape != target.shape:
        raise ValueError(f"depth and target must be [H, W] of one shape, got {depth.shape} and {target.shape}")
    if weight is not None:
        weight = np.asarray(weight, np.float64)
        if weight.shape != depth.shape:
            raise ValueError(f"weight must be [H, W] = {depth.shape}, got {weight.shape}")
    loc = mode == "local"
    P = patchify(depth, patch)
    if not loc and image_std is None:
        image_std = depth.std(ddof=1)  # detached
    x, cache = _normalize_fwd(P, None if loc else float(image_std))
    y, _ = _normalize_fwd(patchify(target, patch), None if loc else target.std(ddof=1))
    diff = x - y
    mask = np.abs(diff) > margin
    cnt = int(mask.sum())
    if cnt == 0:
        return 0.0, np.zeros_like(depth)
    wp = np.ones_like(diff) if weight is None else patchify(weight, patch)
    loss = float((wp[mask] * diff[mask] ** 2).sum() / cnt)
    g = np.where(mask, 2.0 * wp * diff / cnt, 0.0)
    return loss, unpatchify(_normalize_bwd(g, P, cache, loc), patch, depth.shape)


def global_local_depth_loss(depth, target, patch_local: int, patch_global: int, margin: float,
                            w_local: float = 0.1, w_global: float = 1.0,
                            weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """DNGaussian's depth loss: w_local * local(patch_local) + w_global * global(patch_global),
    each term with the per-pixel `weight` of `depth_norm_loss_fwd_bwd` (None: unweighted)."""
    l1, g1 = depth_norm_loss_fwd_bwd(depth, target, patch_local, margin, "local", weight=weight)
    l2, g2 = depth_norm_loss_fwd_bwd(depth, target, patch_global, margin, "global", weight=weight)
    return w_local * l1 + w_global * l2, w_local * g1 + w_global * g2


def depth_confidence_weights(confidence: np.ndarray, strength: float) -> np.ndarray:
    """Per-pixel weights of the depth loss from a prior's confidence c in [0, 1]:
    w = (1 - strength) + strength * c, float32 [H, W] (what the kernels read). strength 0 gives
    all ones (the unweighted loss), 1 the confidence itself (LossConfig.depth_confidence)."""
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"depth confidence strength must be in [0, 1], got {strength}")
    c = np.asarray(confidence, np.float64)
    if c.ndim != 2:
        raise ValueError(f"confidence must be [H, W], got shape {c.shape}")
    if not np.isfinite(c).all():
        raise ValueError("confidence has non-finite values")
    c = np.clip(c, 0.0, 1.0)
    return np.ascontiguousarray((1.0 - strength) + strength * c, np.float32)
# }}}

# {{{ depth smoothness

DNG_MONO_SPAN = 65535.0 / 255.0  # DNGaussian's D_mono = 255 - PNG16 / 255 spans [0, 257]


def depth_smooth_weights(target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge weights of DNGaussian's depth smoothness (`utils/loss_utils.py` loss_depth_smoothness,
    with img = the mono depth, docs/method.md §2.3): wx[y, x] = exp(-|T[y, x] - T[y, x+1]|) and
    wy[y, x] = exp(-|T[y, x] - T[y+1, x]|), each [H, W] float64, 0 in the last column / row.

    T is the target mapped affinely onto [0, DNG_MONO_SPAN] by its min and max (the span of
    DNGaussian's 16-bit-PNG target, whose DPT maps fill the 16-bit range). Proposal: our priors
    come in other units (stereo: metric depth), and exp(-|grad|) depends on the units; a constant
    target gives all weights 1. Non-finite target values are an error."""
    t = np.asarray(target, np.float64)
    if t.ndim != 2:
        raise ValueError(f"depth_smooth_weights: target must be [H, W], got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError("depth_smooth_weights: the depth target has non-finite values")
    lo, hi = float(t.min()), float(t.max())
    m = (t - lo) * (DNG_MONO_SPAN / (hi - lo)) if hi > lo else np.zeros_like(t)
    wx = np.zeros_like(t)
    wy = np.zeros_like(t)
    wx[:, :-1] = np.exp(-np.abs(m[:, :-1] - m[:, 1:]))
    wy[:-1, :] = np.exp(-np.abs(m[:-1, :] - m[1:, :]))
    return wx, wy


def depth_smooth_fwd_bwd(depth: np.ndarray, wx: np.ndarray, wy: np.ndarray) -> tuple[float, np.ndarray]:
    """(sum |D[x] - D[x+1]| wx + sum |D[y] - D[y+1]| wy) / (sum wx + sum wy) and its gradient
    w.r.t. the rendered depth D [H, W] (sign(0) = 0, as torch's abs). Weights from
    `depth_smooth_weights`; kernels/depth_loss.cl fuses its gradient into dl_grad and computes its
    loss in depth_smooth_rows."""
    d = np.asarray(depth, np.float64)
    wx = np.asarray(wx, np.float64)
    wy = np.asarray(wy, np.float64)
    tot = float(wx.sum() + wy.sum())
    if tot <= 0:
        return 0.0, np.zeros_like(d)
    dx = d[:, :-1] - d[:, 1:]
    dy = d[:-1, :] - d[1:, :]
    loss = float((np.abs(dx) * wx[:, :-1]).sum() + (np.abs(dy) * wy[:-1, :]).sum()) / tot
    gx = np.sign(dx) * wx[:, :-1]
    gy = np.sign(dy) * wy[:-1, :]
    v = np.zeros_like(d)
    v[:, :-1] += gx
    v[:, 1:] -= gx
    v[:-1, :] += gy
    v[1:, :] -= gy
    return loss, v / tot


class DepthSmoothWeights:
    """The edge weights of one view's depth smoothness term (`depth_smooth_weights`): wx, wy
    [H, W] float32 (what the kernels read) and inv_sum = 1 / (sum wx + sum wy) of those. Built
    once per training view (the trainers' upload_depth_targets)."""

    def __init__(self, target: np.ndarray):
        wx, wy = depth_smooth_weights(target)
        self.wx = np.ascontiguousarray(wx, np.float32)
        self.wy = np.ascontiguousarray(wy, np.float32)
        # the sum of the float32 weights (in float64), as the reference sums what the kernels read
        tot = float(self.wx.sum(dtype=np.float64) + self.wy.sum(dtype=np.float64))
        self.inv_sum = 1.0 / tot if tot > 0 else 0.0
# }}}


def depth_loss(depth: np.ndarray, target: np.ndarray, p_local: int, p_global: int, margin: float,
               w_local: float = 0.1, w_global: float = 1.0, smooth=None,
               weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The reference backend's depth loss: (loss, float32 dL/d depth) of `global_local_depth_loss`
    (per-pixel `weight` or None) plus, with `smooth` = (DepthSmoothWeights, w_smooth) and
    w_smooth != 0, w_smooth times `depth_smooth_fwd_bwd`."""
    loss, v = global_local_depth_loss(depth, target, p_local, p_global, margin, w_local, w_global, weight)
    if smooth is not None and smooth[1] != 0:
        sw, ws = smooth
        ls, vs = depth_smooth_fwd_bwd(depth, sw.wx, sw.wy)
        loss, v = loss + ws * ls, v + ws * vs
    return loss, v.astype(np.float32)


# {{{ regularize: DNGaussian's penalties on the raw parameters
def shape_reg(log_scales: np.ndarray) -> tuple[float, np.ndarray]:
    """mean over Gaussians of max scale / min scale; gradient w.r.t. log_scales [N, 3]
    (d/d log s of exp(a)/exp(b) is +ratio at the max axis and -ratio at the min axis; ties go to
    the first axis, as torch.max/min; an isotropic Gaussian gets zero)."""
    ls = np.asarray(log_scales, np.float64)
    n = ls.shape[0]
    g = np.zeros_like(ls)
    if n == 0:
        return 0.0, g
    imax, imin = ls.argmax(axis=1), ls.argmin(axis=1)
    r = np.arange(n)
    ratio = np.exp(ls[r, imax] - ls[r, imin])
    np.add.at(g, (r, imax), ratio / n)
    np.add.at(g, (r, imin), -ratio / n)
    return float(ratio.mean()), g


def scale_reg(log_scales: np.ndarray) -> tuple[float, np.ndarray]:
    """mean over Gaussians of (max scale)^2; gradient w.r.t. log_scales (2 s_max^2 / N at the max axis)."""
    ls = np.asarray(log_scales, np.float64)
    n = ls.shape[0]
    g = np.zeros_like(ls)
    if n == 0:
        return 0.0, g
    imax = ls.argmax(axis=1)
    r = np.arange(n)
    s2 = np.exp(2.0 * ls[r, imax])
    g[r, imax] = 2.0 * s2 / n
    return float(s2.mean()), g


OPACITY_SPLIT = 0.2  # opacity_reg's split (OPA_SPLIT in kernels/regularize.cl)


def opacity_reg(opacity_logits: np.ndarray, split: float = OPACITY_SPLIT) -> tuple[float, np.ndarray]:
    """DNGaussian's opa_pena = 1 - mean(o^2 | o > 0.2) + mean((1 - o)^2 | o < 0.2), o = sigmoid(logit);
    gradient w.r.t. the logits.  An empty subset contributes 0 to that mean (torch: NaN) and its
    "1 -" stays (value 1 when no opacity exceeds 0.2, mirroring the formula's constant)."""
    a = np.asarray(opacity_logits, np.float64)
    o = 1.0 / (1.0 + np.exp(-a))
    hi, lo = o > split, o < split
    nh, nl = int(hi.sum()), int(lo.sum())
    val = 1.0
    go = np.zeros_like(o)
    if nh:
        val -= float((o[hi] ** 2).mean())
        go[hi] = -2.0 * o[hi] / nh
    if nl:
        val += float(((1.0 - o[lo]) ** 2).mean())
        go[lo] = -2.0 * (1.0 - o[lo]) / nl
    return val, go * o * (1.0 - o)


def regularize_fwd_bwd(params: dict, shape_pena: float = 0.0, scale_pena: float = 0.0,
                       opa_pena: float = 0.0) -> tuple[float, dict[str, np.ndarray]]:
    """shape_pena * shape + scale_pena * scale + opa_pena * opacity (DNGaussian, added to the
    photometric loss) of the raw parameters `params` (name -> array, PARAM_NAMES); gradients
    (float32) only for the fields with a non-zero weight: "log_scales", "opacity_logits".
    kernels/regularize.cl computes the same gradients on the device."""
    loss, grads = 0.0, {}
    if shape_pena or scale_pena:
        g = np.zeros(params["log_scales"].shape)
        if shape_pena:
            v, gs = shape_reg(params["log_scales"])
            loss += shape_pena * v
            g += shape_pena * gs
        if scale_pena:
            v, gs = scale_reg(params["log_scales"])
            loss += scale_pena * v
            g += scale_pena * gs
        grads["log_scales"] = g.astype(np.float32)
    if opa_pena:
        v, go = opacity_reg(params["opacity_logits"])
        loss += opa_pena * v
        grads["opacity_logits"] = (opa_pena * go).astype(np.float32)
    return loss, grads


REG_VALUE_COLS = 6  # the per-chunk sums of kernels/regularize.cl regularize_value


def regularize_value_sums(params: dict, chunk: int = 256) -> np.ndarray:
    """kernels/regularize.cl regularize_value's per-chunk sums [ceil(N / chunk), REG_VALUE_COLS]
    (float64): max/min scale, max scale^2, o^2 over o > OPACITY_SPLIT, (1 - o)^2 over o <
    OPACITY_SPLIT, and the two counts."""
    ls = np.asarray(params["log_scales"], np.float64).reshape(-1, 3)
    o = 1.0 / (1.0 + np.exp(-np.asarray(params["opacity_logits"], np.float64).reshape(-1)))
    n = len(ls)
    r = np.arange(n)
    imax, imin = ls.argmax(axis=1), ls.argmin(axis=1)
    hi, lo = o > OPACITY_SPLIT, o < OPACITY_SPLIT
    cols = np.stack([np.exp(ls[r, imax] - ls[r, imin]), np.exp(2.0 * ls[r, imax]), np.where(hi, o * o, 0.0),
                     np.where(lo, (1.0 - o) ** 2, 0.0), hi, lo], axis=1)
    c = -(-n // chunk)
    out = np.zeros((c, REG_VALUE_COLS))
    np.add.at(out, r // chunk, cols)
    return out


def regularize_value(sums: np.ndarray, n: int, shape_pena: float = 0.0, scale_pena: float = 0.0,
                     opa_pena: float = 0.0) -> float:
    """regularize_fwd_bwd's value from per-chunk sums (`regularize_value_sums`, or the kernel's),
    the chunks added in float64: what the device trainer's `read_regularize` returns."""
    s = np.sum(np.asarray(sums, np.float64).reshape(-1, REG_VALUE_COLS), axis=0)
    loss = 0.0
    if shape_pena and n:
        loss += shape_pena * float(s[0] / n)
    if scale_pena and n:
        loss += scale_pena * float(s[1] / n)
    if opa_pena:
        nh, nl = s[4], s[5]  # counts (exact in float64)
        val = 1.0
        if nh > 0:
            val -= float(s[2] / nh)
        if nl > 0:
            val += float(s[3] / nl)
        loss += opa_pena * val
    return loss
# }}}


# {{{ mse: the train PSNR's mean squared error (kernels/mse.cl)
def mse_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per row of [H, W, 3] images the float64 sum of (x - y)^2 (kernels/mse.cl mse_rows)."""
    d = np.asarray(x, np.float64) - np.asarray(y, np.float64)
    return np.sum(np.square(d).reshape(d.shape[0], -1), axis=1)


def mse(x: np.ndarray, y: np.ndarray) -> float:
    """mean((x - y)^2) in float64: the train PSNR's error, -10 log10(mse) (reings.train)."""
    return float(np.mean(np.square(np.asarray(x, np.float64) - y)))
# }}}


# {{{ bg_alpha: DNGaussian's DTU background opacity term

def bg_alpha_fwd_bwd(alpha: np.ndarray, mask: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean of alpha^2 over the pixels of `mask`, dL/d alpha = 2 alpha / count there, 0 elsewhere),
    float64; (0, zeros) for an empty mask (kernels/bg_alpha.cl)."""
    a = np.asarray(alpha, np.float64)
    m = np.asarray(mask, bool)
    if a.shape != m.shape:
        raise ValueError(f"bg_alpha: alpha {a.shape} and mask {m.shape} differ")
    n = int(m.sum())
    if n == 0:
        return 0.0, np.zeros_like(a)
    return float(np.mean(a[m] ** 2)), np.where(m, 2.0 * a / n, 0.0)
# }}}


# {{{ depth_metric: the rendered depth against the prior's metric depth (kernels/depth_metric.cl)
def depth_metric_valid(target: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The pixels the metric depth term sees: weight > 0 and a positive, finite target."""
    t = np.asarray(target, np.float64)
    c = np.asarray(weight, np.float64)
    with np.errstate(invalid="ignore"):
        return (c > 0) & (t > 0) & np.isfinite(t)


def depth_metric_scale(target: np.ndarray, weight: np.ndarray, w: float) -> float:
    """w / S, S the sum of the weights over the valid pixels (0 where there are none): the one
    number per view that the kernel takes (as float32)."""
    s = float(np.sum(np.asarray(weight, np.float64)[depth_metric_valid(target, weight)]))
    return float(w) / s if s > 0 else 0.0


def depth_metric_fwd_bwd(depth: np.ndarray, alpha: np.ndarray, target: np.ndarray, weight: np.ndarray,
                         w: float) -> tuple[float, np.ndarray]:
    """The metric depth term, float64 (docs/method.md §10):
        L = w / S * sum_p c_p |D_p - a_p t_p| / t_p,  S = sum of c_p over the valid pixels
    with the alpha a held constant. Returns (L, dL/dD): (w / S) c_p sign(D_p - a_p t_p) / t_p on the
    valid pixels (0 at a tie and for a NaN depth), 0 elsewhere; a non-finite D - a t adds nothing to L."""
    d = np.asarray(depth, np.float64)
    a = np.asarray(alpha, np.float64)
    t = np.asarray(target, np.float64)
    c = np.asarray(weight, np.float64)
    if not d.shape == a.shape == t.shape == c.shape:
        raise ValueError(f"depth_metric: depth {d.shape}, alpha {a.shape}, target {t.shape}, weight {c.shape} differ")
    ok = depth_metric_valid(t, c)
    scale = depth_metric_scale(t, c, w)
    ts = np.where(ok, t, 1.0)
    with np.errstate(invalid="ignore"):
        r = np.where(ok, d - a * ts, 0.0)
    r = np.where(np.isnan(r), 0.0, r)
    loss = scale * float(np.sum(np.where(ok & np.isfinite(r), c * np.abs(r) / ts, 0.0)))
    return loss, np.where(ok, scale * c * np.sign(r) / ts, 0.0)
# }}}
