"""DNGaussian's DTU background rules, host side (docs/method.md §2.5; all off unless
`LossConfig.dark_background` / `DensifyConfig.dark_white_rules`).

    dark_background_mask   which training pixels are background: RGB max < threshold (30/255) and
                           the `column` (49) pixels directly above, those inside the image, too
    zero_background        the training image with those pixels set to 0 (the ground truth the
                           photometric loss sees)
    dark_white_rules       at a densification step: "black" Gaussians (colour max < 20/255) get
                           their gradient accumulator divided by 10 and opacity 0.1; "white" ones
                           (colour min > 240/255) their accumulator halved

Source: Fictionarry/DNGaussian `train_dtu.py` at 14c3c6a41a32d5182801c11dfd99515b76281b7c (read,
not copied): the mask is `max over RGB < 30/255` (15/255 for scan110), then for i = 1..49
`bg_mask[:, i:] *= clone[:, :-i]` over the image rows, so a pixel needs the original darkness of
every row from y - 49 to y that exists (rows above the image top are not required); then
`gt_image[bg_mask] = 0`. At densification (`iteration % interval == 0`), the per-Gaussian colour
of the current view's render: `xyz_gradient_accum[black] /= 10`, `_opacity[black] = logit(0.1)`,
`xyz_gradient_accum[white] /= 2` (its opacity set is gated on `iteration % 2001 == 0` and never
fires with a 100-iteration interval); scan110 is exempt from both, scan21 and scan114 from the
white rule (per-scan exceptions are not reproduced here: the same defaults for every scene).

Deviation: DNGaussian's per-Gaussian colour is its neural colour field's for the current view;
here it is the SH DC colour (SH_C0 * f_dc + 0.5, the view-independent part) of the state.
Not built: DNGaussian also replaces the rendered and the target depth by their foreground means on
background pixels in the depth terms.
"""
from __future__ import annotations

import numpy as np

from .types import ACCUM

DARK_THRESHOLD = 30.0 / 255.0
DARK_COLUMN = 49
BLACK_MAX = 20.0 / 255.0
WHITE_MIN = 240.0 / 255.0
SH_C0 = 0.28209479177387814


def dark_background_mask(image: np.ndarray, threshold: float = DARK_THRESHOLD, column: int = DARK_COLUMN) -> np.ndarray:
    """[H, W] bool: max over RGB < threshold at (y, x) and at (y - i, x) for i = 1..column with
    y - i >= 0. image: [H, W, 3] in [0, 1]."""
    im = np.asarray(image)
    if im.ndim != 3 or im.shape[2] != 3:
        raise ValueError(f"dark_background_mask: image must be [H, W, 3], got {im.shape}")
    if column < 0:
        raise ValueError(f"dark_background_mask: column must be >= 0, got {column}")
    dark = im.max(axis=2) < threshold
    # run length of dark pixels ending at each row (column-wise), via the last non-dark row index
    h = dark.shape[0]
    rows = np.arange(h)[:, None]
    last_bright = np.where(dark, -1, rows)
    last_bright = np.maximum.accumulate(last_bright, axis=0)  # index of the last non-dark row <= y (-1: none)
    return dark & (rows - last_bright > np.minimum(rows, column))


def zero_background(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A float32 copy of `image` with the pixels of `mask` set to 0."""
    out = np.array(image, dtype=np.float32)
    out[np.asarray(mask, bool)] = 0.0
    return out


def dark_white_rules(state, black_max: float = BLACK_MAX, white_min: float = WHITE_MIN) -> dict:
    """DNGaussian's black / white Gaussian rules on a TrainState, in place (before its
    densify-and-prune): returns {"black": count, "white": count}."""
    c = SH_C0 * np.asarray(state.params["sh_dc"], np.float64)[:, 0, :] + 0.5  # [N, 3]
    black = c.max(axis=1) < black_max
    white = c.min(axis=1) > white_min
    acc = state.stats[ACCUM]
    acc[black] = acc[black] / np.float32(10)
    acc[white] = acc[white] / np.float32(2)
    logits = state.params["opacity_logits"]
    logits[black] = np.float32(np.log(0.1 / 0.9))
    return {"black": int(black.sum()), "white": int(white.sum())}
