"""ReInGS re-initialisation (paper §3, Eq. 3-8): the point sets the pipeline's stages build.

    ehps_init         EHPS: a grid plus random points in the expanded SfM box
    stereo_seed_points  EHPS's optional extra: confident pixels of the stereo prior, back-projected
    stereo_box        the scene box from those pixels, when SfM triangulates too few points
    ivps_view_scores  IVPS, one view: the pixel score Omega_P and the depth to back-project with
    ivps_points       IVPS: pixels drawn with p ~ Omega_P, back-projected (backproject_pixels)
    gaussian_importance  Omega_G (Eq. 7): alpha*T per Gaussian summed over views and pixels
                      (defined in reings.rendering, where the training loop's pruning reaches it too)
    cvps_select       CVPS: Gaussians drawn with p ~ Omega_G
    prune_keep_indices   the final prune: the top fraction by Omega_G, deterministically

Settings come from `reings.config.ReInGSConfig`; the stage order, timing and records are
`reings.pipeline`'s. Every random draw takes the caller's numpy Generator, in the order the
pipeline calls them (the run's seed fixes them all).
"""
from __future__ import annotations

import numpy as np

from .config import ReInGSConfig
from .rendering import gaussian_importance  # noqa: F401  (Omega_G: CVPS, the final prune, the pipeline)
from .train import SH_C0, gaussians_from_points, random_points_in_box
from .types import Gaussians


def ehps_init(extent_lo, extent_hi, rc: ReInGSConfig, sh_degree: int, rng, seeds=None) -> object:
    """EHPS: expand the SfM box by gamma about its centre; a uniform grid of ~beta1*max side points
    at cell centres plus beta2*max side uniform random points (paper §3). `seeds` = (points,
    colours) adds coloured points (`stereo_seed_points`); the 3-NN scales are then taken over all."""
    lo, hi = np.asarray(extent_lo, np.float64), np.asarray(extent_hi, np.float64)
    c, half = (lo + hi) / 2, (hi - lo) / 2 * rc.gamma
    lo2, hi2 = c - half, c + half
    side = hi2 - lo2
    n_uni = int(rc.beta1 * side.max())
    n_rand = int(rc.beta2 * side.max())
    if n_uni + n_rand < rc.min_init_points:  # scenes in small units: keep the 4:1 ratio
        s = rc.min_init_points / max(n_uni + n_rand, 1)
        n_uni, n_rand = int(n_uni * s), int(n_rand * s)
    step = (np.prod(side) / max(n_uni, 1)) ** (1 / 3)
    counts = np.maximum(1, np.round(side / step)).astype(int)
    axes = [lo2[a] + (np.arange(counts[a]) + 0.5) * side[a] / counts[a] for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    pts = np.concatenate([grid, random_points_in_box(lo2, hi2, n_rand, rng)]).astype(np.float32)
    g = gaussians_from_points(pts, None, sh_degree, rng)
    if seeds is None or not len(seeds[0]):
        return g
    means = np.concatenate([pts, np.asarray(seeds[0], np.float32).reshape(-1, 3)])
    cols = np.concatenate([g.sh[:, 0] * SH_C0 + 0.5, np.asarray(seeds[1], np.float32).reshape(-1, 3)])
    s = gaussians_from_points(means, cols, sh_degree, rng)  # the 3-NN scales over every point
    sh = s.sh.copy()
    sh[:len(g), 0] = g.sh[:, 0]  # EHPS's own colours exactly as drawn
    return Gaussians(s.means, s.quats, s.log_scales, s.opacity_logits, sh)


def _confident(depth, conf, min_conf: float):
    """(confidence, depth, qualifying mask) of one view's prior, flat float64: confidence >=
    min_conf and > 0 (0 marks a filled pixel, never used), a finite positive depth."""
    c = np.asarray(conf, np.float64).ravel()
    z = np.asarray(depth, np.float64).ravel()
    return c, z, (c >= min_conf) & (c > 0) & np.isfinite(z) & (z > 0)


def stereo_box(train, priors, confidences, min_conf: float, quantile: float = 0.01):
    """The scene box from the stereo prior when SfM triangulates too few points: every training
    pixel with confidence >= min_conf (and > 0), back-projected with the prior's depth; the box spans their
    [quantile, 1 - quantile] range per axis. None when fewer than 1000 pixels qualify. The points
    (float64) go with it, as SfM's do (the scene's typical depth is taken from them)."""
    from .data.sfm import SfmExtent

    pts, cols = [], []
    for img, cam, depth, conf in zip(train.images, train.cameras, priors, confidences):
        if depth is None or conf is None:
            continue
        _, z, ok = _confident(depth, conf, min_conf)
        idx = np.flatnonzero(ok)
        pts.append(backproject_pixels(cam, idx, z[idx]))
        cols.append(np.asarray(img, np.float32).reshape(-1, 3)[idx])
    if not pts or sum(map(len, pts)) < 1000:
        return None
    pts, cols = np.concatenate(pts), np.concatenate(cols)
    lo, hi = np.quantile(pts, quantile, axis=0), np.quantile(pts, 1 - quantile, axis=0)
    return SfmExtent(lo, hi, "stereo", pts, cols)


def stereo_seed_points(train, priors, confidences, fraction: float, min_conf: float, rng):
    """Points where the stereo prior is sure of its depth (not in the paper; `ReInGSConfig.stereo_seeds`).

    Per training view, up to round(fraction * H * W) pixels with confidence >= min_conf (and > 0) are drawn
    without replacement with p ~ confidence, back-projected with the prior's metric z-depth and
    coloured with the training pixel. Only the training views' images and prior enter. Returns
    (points [n, 3] float32, colours [n, 3] float32); empty arrays when no pixel qualifies."""
    pts, cols = [], []
    for img, cam, depth, conf in zip(train.images, train.cameras, priors, confidences):
        if depth is None or conf is None:
            continue
        c, z, ok = _confident(depth, conf, min_conf)
        n = min(int(round(fraction * cam.width * cam.height)), int(ok.sum()))
        if n == 0:
            continue
        p = np.where(ok, c, 0.0)
        idx = rng.choice(c.size, size=n, replace=False, p=p / p.sum())
        pts.append(backproject_pixels(cam, idx, z[idx]))
        cols.append(np.asarray(img).reshape(-1, 3)[idx])
    if not pts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.float32)


def _zscore(x, m):
    v = x[m]
    return (x - v.mean()) / (v.std() + 1e-8)


def backproject_pixels(cam, idx, z) -> np.ndarray:
    """World points [n, 3] (float64) of the flat pixel indices `idx` (row-major, v * W + u) at
    camera-space z-depths `z`: X_cam = z * ((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1) (pixel
    centres at +0.5, reings.types), X_world = R^T (X_cam - t) with viewmat = [R | t] world-to-camera."""
    idx = np.asarray(idx)
    z = np.asarray(z, np.float64)
    v, u = np.divmod(idx, cam.width)
    x = (u + 0.5 - cam.cx) / cam.fx * z
    y = (v + 0.5 - cam.cy) / cam.fy * z
    Xc = np.stack([x, y, z], 1)
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    return (Xc - t) @ R  # R^T (Xc - t)


def ivps_view_scores(g, cam, prior, rc: ReInGSConfig, device, bg, near):
    """One training view of IVPS: (score [H*W] (0 = never drawn), depth [H, W] for back-projection,
    diagnostics dict). Omega_P = delta*Omega_D + (1-delta)*Omega_T (Eq. 3-6); depth (rc.ivps_depth)
    = the hard render's (every opacity rc.ivps_hard_opacity, Eq. 5) or the normal render's depth / alpha."""
    from .rendering import render

    hard = render(g, cam, device, bg, near, opacity_override=rc.ivps_hard_opacity)
    soft = render(g, cam, device, bg, near)
    valid = hard.alpha >= rc.ivps_min_alpha  # some Gaussian covers the pixel
    if rc.ivps_depth == "hard":
        depth = np.where(valid, hard.depth / np.maximum(hard.alpha, 1e-6), 0.0)
    else:  # a weighted mean of the covering Gaussians' z; alpha exactly 0 would give depth 0
        valid &= soft.alpha > 1e-6
        depth = np.where(valid, soft.depth / np.maximum(soft.alpha, 1e-6), 0.0)
    omega_t = soft.final_T if soft.final_T is not None else 1.0 - soft.alpha
    omega_d = np.zeros_like(depth)
    if prior is not None and valid.sum() > 16:
        e = np.abs(_zscore(depth, valid) - _zscore(np.asarray(prior, np.float64), valid))
        ev = e[valid]
        omega_d = 1.0 - (e - ev.min()) / max(ev.max() - ev.min(), 1e-12)
    score = rc.delta * omega_d + (1 - rc.delta) * omega_t
    score = np.where(valid, np.maximum(score, 1e-6), 0.0).ravel()
    return score, depth, {"valid": valid, "omega_t": omega_t, "omega_d": omega_d}


def ivps_points(g, train, priors, rc: ReInGSConfig, device, bg, near, rng):
    """IVPS (Eq. 4-6): per view, Omega_P = delta*Omega_D + (1-delta)*Omega_T; draw ~10% of the
    pixels without replacement with p ~ Omega_P; back-project with the hard-render depth."""
    pts, cols = [], []
    for vi, (img, cam) in enumerate(zip(train.images, train.cameras)):
        prior = priors[vi] if priors is not None else None
        score, depth, _ = ivps_view_scores(g, cam, prior, rc, device, bg, near)
        n = min(int(round(rc.ivps_fraction * cam.width * cam.height)), int((score > 0).sum()))
        if n == 0:
            continue
        idx = rng.choice(score.size, size=n, replace=False, p=score / score.sum())
        pts.append(backproject_pixels(cam, idx, depth.ravel()[idx]))
        cols.append(np.asarray(img).reshape(-1, 3)[idx])
    if not pts:
        raise RuntimeError("IVPS: the coarse Gaussians cover no pixel of any training view")
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.float32)


def prune_keep_indices(omega, keep: float) -> np.ndarray:
    """Sorted indices of the round(keep * N) Gaussians (at least 1 when N > 0) of highest `omega`;
    deterministic: a stable sort of -omega, so ties keep the lower index."""
    omega = np.asarray(omega, np.float64)
    if not 0.0 < float(keep) <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep!r}")
    n = len(omega)
    k = min(n, max(1, int(round(float(keep) * n)))) if n else 0
    return np.sort(np.argsort(-omega, kind="stable")[:k])


def cvps_select(g, train, rc: ReInGSConfig, device, bg, near, rng):
    """CVPS (Eq. 7-8): Omega_G = sum over views and pixels of alpha*T per Gaussian; draw
    rc.cvps_fraction of them (the paper: 40%) without replacement with p ~ Omega_G (+ a tiny
    epsilon so zero-score Gaussians are possible)."""
    omega = gaussian_importance(g, train.cameras, device, bg, near)
    p = omega + 1e-12 * max(omega.max(), 1.0)
    n = max(1, int(round(rc.cvps_fraction * len(g))))
    return np.sort(rng.choice(len(g), size=n, replace=False, p=p / p.sum()))
