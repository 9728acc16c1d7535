"""Densification: screen-space gradient statistics, clone / split / prune (3DGS with DNGaussian's
thresholds), opacity reset, `clean_views`, an optional cap on the Gaussian count.

Units (docs/method.md §5.4): the 3DGS thresholds (0.0002; DNGaussian 0.0013) assume the norm of
dL/d(means2d) in NDC-scaled units, i.e. the pixel-space gradient times (W/2, H/2).  `render_vjp`
returns raw-field gradients only, so the fit loop passes the per-view pixel-space v_means2d (from
the backend) through `ndc_grad_norm` into `accumulate`, once per photometric backward (DNGaussian:
only the photometric render feeds the statistics).

Statistics live in `TrainState.stats` (so `apply_index_op` keeps them aligned):
    grad2d_accum [N] float32  sum of NDC gradient norms over the views where the Gaussian was visible
    grad2d_count [N] int32    number of those views
    max_radii2d  [N] float32  largest screen radius seen (for 3DGS's screen-size pruning)

The loop calls, per iteration:  `accumulate(...)` after the photometric backward, then
`maybe_densify(state, cfg, iteration, extent, rng)` (densify + prune + opacity reset on schedule).
"""
from __future__ import annotations

import numpy as np

from .backends.reference_state import densify_accumulate, ndc_grad_norm, zero_stats
from .state import TrainState, apply_index_op, reset_moments
from .types import ACCUM, COUNT, RADII

__all__ = ["ACCUM", "COUNT", "RADII", "init_stats", "ndc_grad_norm", "accumulate", "mean_grads",
           "densify_and_prune", "reset_opacity", "clean_views", "prune_unseen", "schedule", "maybe_densify"]


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def _logit(p):
    p = np.asarray(p, np.float64)
    return np.log(p / (1.0 - p))


def quat_to_rotmat(quats: np.ndarray) -> np.ndarray:
    """[N,4] (w,x,y,z), any norm -> [N,3,3] rotation matrices (3DGS `build_rotation`)."""
    q = np.asarray(quats, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


# {{{ statistics
def init_stats(state: TrainState) -> None:
    """(Re)set the densification statistics of `state` to zeros."""
    state.stats.update(zero_stats(len(state)))


def accumulate(state: TrainState, grad_norms: np.ndarray, visible: np.ndarray, radii: np.ndarray | None = None) -> None:
    """3DGS `add_densification_stats` for one view on `state.stats`: for the visible Gaussians
    (radius > 0), add the NDC gradient norm (`ndc_grad_norm`) and count the view; track the max
    screen radius. The arithmetic is `reings.backends.reference_state.densify_accumulate`, the
    twin of kernels/densify_accumulate.cl."""
    if ACCUM not in state.stats:
        init_stats(state)
    densify_accumulate(state.stats, grad_norms, visible, radii)


def mean_grads(state: TrainState) -> np.ndarray:
    """accum / count per Gaussian (0 where never visible, as 3DGS's `grads[grads.isnan()] = 0`)."""
    if ACCUM not in state.stats:
        return np.zeros(len(state), np.float32)
    c = state.stats[COUNT]
    return np.where(c > 0, state.stats[ACCUM] / np.maximum(c, 1), 0.0).astype(np.float32)
# }}}


# {{{ grow and prune
def _cap_candidates(grads, cand, cost, budget):
    """Keep the highest-gradient candidates whose summed cost (new rows) fits the budget."""
    idx = np.flatnonzero(cand)
    if cost[idx].sum() <= budget:
        return cand
    order = idx[np.argsort(-grads[idx], kind="stable")]
    fits = order[np.cumsum(cost[order]) <= budget]
    out = np.zeros_like(cand)
    out[fits] = True
    return out


def densify_and_prune(state: TrainState, cfg, extent: float, rng: np.random.Generator,
                      size_prune: bool = False) -> dict:
    """One 3DGS `densify_and_prune` with the thresholds of `cfg` (a DensifyConfig):

    grad = accum / count;  candidates: grad >= grad_threshold (and opacity > split_opacity_thresh
    when set, DNGaussian);  clone those with max scale <= percent_dense * extent (a copy, zero
    moments), split the others into split_n children (means sampled from N(0, diag(scale^2))
    rotated by R, plus the mean; scale / (0.8 * split_n); other fields copied; parent removed);
    then prune opacity < prune_opacity (and, when size_prune, screen radius > max_screen_size or
    max scale > max_world_size * extent).  With max_gaussians set, growth is limited to the
    highest-gradient candidates that fit.  The statistics are reset afterwards.
    Returns counts {"cloned", "split", "pruned", "n"}."""
    n0 = len(state)
    grads = mean_grads(state)
    p = state.params
    max_scale = np.exp(p["log_scales"].astype(np.float64)).max(axis=1) if n0 else np.zeros(0)
    cand = grads >= cfg.grad_threshold
    if cfg.split_opacity_thresh is not None:
        cand &= _sigmoid(p["opacity_logits"]) > cfg.split_opacity_thresh
    small = max_scale <= cfg.percent_dense * extent
    clone, split = cand & small, cand & ~small
    if cfg.max_gaussians is not None:
        cost = np.where(clone, 1, cfg.split_n - 1)
        keep_c = _cap_candidates(grads, clone | split, cost, max(0, cfg.max_gaussians - n0))
        clone, split = clone & keep_c, split & keep_c

    # split children (3DGS densify_and_split: tensors repeated N times, i.e. tiled [sel; sel])
    sel = np.flatnonzero(split)
    k = cfg.split_n
    children = {}
    if len(sel):
        scales = np.exp(p["log_scales"][sel].astype(np.float64))  # [S,3]
        stds = np.tile(scales, (k, 1))
        samples = rng.normal(size=stds.shape) * stds  # [kS,3]
        rots = np.tile(quat_to_rotmat(p["quats"][sel]), (k, 1, 1))
        children["means"] = (np.einsum("nij,nj->ni", rots, samples) + np.tile(p["means"][sel], (k, 1))).astype(np.float32)
        children["log_scales"] = np.log(stds / (0.8 * k)).astype(np.float32)
        for name in p:
            if name not in children:
                children[name] = np.tile(p[name][sel], (k,) + (1,) * (p[name].ndim - 1))
    # prune (over the grown set [kept; clones; children], as 3DGS), applied with the growth in one
    # index op: the grown set's columns the tests read are assembled without copying every array
    ki, di = np.flatnonzero(~split), np.flatnonzero(clone)

    def grown(name: str, a: np.ndarray) -> np.ndarray:
        extra = [np.asarray(children[name], np.float32)] if children else []  # as apply_index_op casts them
        return np.concatenate([a[ki], a[di]] + extra, axis=0)

    prune = _sigmoid(grown("opacity_logits", p["opacity_logits"])) < cfg.prune_opacity
    if size_prune:
        if cfg.max_screen_size is not None:  # the new rows' statistics are zero
            radii = state.stats[RADII]
            prune |= np.concatenate([radii[ki], np.zeros(len(prune) - len(ki), radii.dtype)]) > cfg.max_screen_size
        if cfg.max_world_size is not None:
            ls = grown("log_scales", p["log_scales"])
            prune |= np.exp(ls.astype(np.float64)).max(axis=1) > cfg.max_world_size * extent
    apply_index_op(state, keep=ki, duplicate=di, append=children or None, then_keep=~prune)
    init_stats(state)
    return {"cloned": int(clone.sum()), "split": int(len(sel)), "pruned": int(prune.sum()), "n": len(state)}


def reset_opacity(state: TrainState, value: float = 0.01) -> None:
    """3DGS `reset_opacity`: opacity = min(opacity, value), Adam moments of the opacities zeroed."""
    o = state.params["opacity_logits"]
    np.minimum(o, np.float32(_logit(value)), out=o)
    reset_moments(state, "opacity_logits")


def clean_views(state: TrainState, visible: np.ndarray) -> int:
    """DNGaussian `clean_views`: drop Gaussians with zero radius in every training view.
    visible: [N] (seen by any view) or [V, N] per-view masks (radii > 0).  Returns how many went."""
    vis = np.asarray(visible, bool)
    if vis.ndim == 2:
        vis = vis.any(axis=0)
    if vis.shape != (len(state),):
        raise ValueError(f"clean_views: visibility of shape {vis.shape}, expected ({len(state)},) or (V, {len(state)})")
    removed = int((~vis).sum())
    if removed:
        apply_index_op(state, keep=vis)
    return removed


def prune_unseen(state: TrainState, seen: np.ndarray) -> int:
    """DensifyConfig.prune_unseen: drop the Gaussians no training pixel blends (`seen`:
    rendering.gaussian_importance over the training views > 0). No loss term of a fit reaches
    them through a training view, so only the regularisers (whose gradients Adam normalises into full-size steps) and the virtual views move
    them; a test view between the training views can still see them (docs/method.md §11).
    Returns how many went."""
    seen = np.asarray(seen, bool)
    if seen.shape != (len(state),):
        raise ValueError(f"prune_unseen: mask of shape {seen.shape}, expected ({len(state)},)")
    removed = int((~seen).sum())
    if not removed or removed == len(state):  # nothing to do; never empty the model
        return 0
    apply_index_op(state, keep=seen)
    return removed


def schedule(cfg, iteration: int) -> tuple[bool, bool]:
    """(densify_and_prune due, opacity reset due) after the optimizer step of `iteration`
    (1-based), the 3DGS/DNGaussian schedule: densify when densify_from < iteration < densify_until
    and iteration % densify_interval == 0; reset opacities every opacity_reset_interval iterations
    while < densify_until. The one definition `maybe_densify` and the device engine (which reads
    its state back only when something is due) both use."""
    if iteration >= cfg.densify_until:
        return False, False
    dens = iteration > cfg.densify_from and iteration % cfg.densify_interval == 0
    reset = bool(cfg.opacity_reset_interval) and iteration % cfg.opacity_reset_interval == 0
    return dens, reset


def maybe_densify(state: TrainState, cfg, iteration: int, extent: float, rng: np.random.Generator) -> dict | None:
    """Run what `schedule` says is due (size pruning after size_prune_from). Returns the counts
    or None."""
    dens, reset = schedule(cfg, iteration)
    out = None
    if dens and cfg.dark_white_rules:  # DTU (reings.background): before densify-and-prune
        from .background import dark_white_rules

        out = {"dark_white": dark_white_rules(state)}
    if dens:
        size_prune = cfg.size_prune_from is not None and iteration > cfg.size_prune_from
        out = dict(out or {}, **densify_and_prune(state, cfg, extent, rng, size_prune=size_prune))
    if reset:
        reset_opacity(state)
        out = dict(out or {}, opacity_reset=True)
    return out
# }}}
