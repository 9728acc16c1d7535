"""Densification: screen-space gradient statistics, clone / split / prune (3DGS with DNGaussian's
thresholds), opacity reset, `clean_views`, an optional cap on the Gaussian count.

Units (docs/method.md §5.4): the 3DGS thresholds (0.0002; DNGaussian 0.0013) assume the norm of
dL/d(means2d) in NDC-scaled units, i.e. the pixel-space gradient times (W/2, H/2).  `render_vjp`
returns raw-field gradients only, so the fit loop passes the per-view pixel-space v_means2d (from
the backend) through `ndc_grad_norm` into `accumulate`, once per photometric backward (DNGaussian:
only the photometric render feeds the statistics).

Statistics live in `TrainState.stats` (so every row edit, a `RowPlan` applied by `apply_rows`, keeps
them aligned):
    grad2d_accum [N] float32  sum of NDC gradient norms over the views where the Gaussian was visible
    grad2d_count [N] int32    number of those views
    max_radii2d  [N] float32  largest screen radius seen (for 3DGS's screen-size pruning)

The loop calls, per iteration:  the trainer's `accumulate` after the photometric backward, then, when
`schedule` says so, `densify_rows(trainer, cfg, iteration, extent, rng, importance)` (densify + prune +
opacity reset + the unseen prune, on the trainer: the decisions on the host from `decision_columns`, the
rows edited where the state lives). `maybe_densify` is the same on a bare TrainState.
"""
from __future__ import annotations

import numpy as np

from .backends.reference_state import HeldRows, apply_rows, densify_accumulate, ndc_grad_norm, zero_stats
from .config import finite_nonneg
from .state import TrainState, apply_index_op, index_plan
from .types import ACCUM, COUNT, RADII, RowPlan

__all__ = ["ACCUM", "COUNT", "RADII", "init_stats", "ndc_grad_norm", "accumulate", "mean_grads",
           "decision_columns", "densify_plan", "densify_and_prune", "reset_opacity", "clean_views", "unseen_plan",
           "prune_unseen", "schedule", "maybe_densify", "densify_rows"]


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
    return _mean_grads(state.stats, len(state))


def _mean_grads(stats: dict, n: int) -> np.ndarray:
    if ACCUM not in stats:
        return np.zeros(n, np.float32)
    c = stats[COUNT]
    return np.where(c > 0, stats[ACCUM] / np.maximum(c, 1), 0.0).astype(np.float32)
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


def decision_columns(cfg) -> tuple[tuple, tuple]:
    """(parameters, statistics) that `densify_plan` (and, with cfg.dark_white_rules, the DTU rules
    before it) read: what a trainer that holds the state elsewhere must bring to the host."""
    params = ("means", "quats", "log_scales", "opacity_logits") + (("sh_dc",) if cfg.dark_white_rules else ())
    return params, (ACCUM, COUNT, RADII)


def densify_plan(params: dict, stats: dict, cfg, extent: float, rng: np.random.Generator,
                 size_prune: bool = False) -> tuple[RowPlan, dict]:
    """One 3DGS `densify_and_prune` decided from the columns `decision_columns` names, as a RowPlan
    (reings.types) of the old rows, with the thresholds of `cfg` (a DensifyConfig):

    grad = accum / count;  candidates: grad >= grad_threshold (and opacity > split_opacity_thresh
    when set, DNGaussian);  clone those with max scale <= percent_dense * extent (a copy, zero
    moments), split the others into split_n children (means sampled from N(0, diag(scale^2))
    rotated by R, plus the mean; scale / (0.8 * split_n); other fields copied; parent removed);
    then prune opacity < prune_opacity (and, when size_prune, screen radius > max_screen_size or
    max scale > max_world_size * extent) over the grown set [kept; clones; children].  With
    max_gaussians set, growth is limited to the highest-gradient candidates that fit.
    Returns (plan, counts {"cloned", "split", "pruned", "n"}); the statistics are reset when the
    plan is applied (`zero_stats`)."""
    p = params
    n0 = len(p["means"])
    grads = _mean_grads(stats, n0)
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

    # split children (3DGS densify_and_split: tensors repeated N times, i.e. tiled [sel; sel]): the
    # parents' rows with new means and scales
    sel = np.flatnonzero(split)
    k = cfg.split_n
    fresh = {}
    if len(sel):
        scales = np.exp(p["log_scales"][sel].astype(np.float64))  # [S,3]
        stds = np.tile(scales, (k, 1))
        samples = rng.normal(size=stds.shape) * stds  # [kS,3]
        rots = np.tile(quat_to_rotmat(p["quats"][sel]), (k, 1, 1))
        fresh["means"] = (np.einsum("nij,nj->ni", rots, samples) + np.tile(p["means"][sel], (k, 1))).astype(np.float32)
        fresh["log_scales"] = np.log(stds / (0.8 * k)).astype(np.float32)
    ki, di = np.flatnonzero(~split), np.flatnonzero(clone)
    src = np.concatenate([ki, di, np.tile(sel, k)])
    grown = RowPlan(src, len(ki), len(ki) + len(di), fresh)
    # prune over the grown set, from the few columns it reads
    prune = _sigmoid(p["opacity_logits"][src]) < cfg.prune_opacity
    if size_prune:
        if cfg.max_screen_size is not None:  # the new rows' statistics are zero
            radii = stats[RADII]
            prune |= np.concatenate([radii[ki], np.zeros(len(prune) - len(ki), radii.dtype)]) > cfg.max_screen_size
        if cfg.max_world_size is not None:
            ls = p["log_scales"][src]
            if len(sel):
                ls[grown.fresh_start:] = fresh["log_scales"]
            prune |= np.exp(ls.astype(np.float64)).max(axis=1) > cfg.max_world_size * extent
    plan = grown.then_keep(~prune)
    return plan, {"cloned": int(clone.sum()), "split": int(len(sel)), "pruned": int(prune.sum()), "n": len(plan)}


def densify_and_prune(state: TrainState, cfg, extent: float, rng: np.random.Generator,
                      size_prune: bool = False) -> dict:
    """`densify_plan` applied to a TrainState (its statistics reset). Returns the counts."""
    if ACCUM not in state.stats:
        init_stats(state)
    plan, counts = densify_plan(state.params, state.stats, cfg, extent, rng, size_prune)
    apply_rows(state.params, state.adam.exp_avg, state.adam.exp_avg_sq, state.stats, plan, zero_stats=True)
    return counts


def reset_opacity(state: TrainState, value: float = 0.01) -> None:
    """3DGS `reset_opacity`: opacity = min(opacity, value), Adam moments of the opacities zeroed."""
    HeldRows(state).reset_opacity(_logit(value))


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


def _means_for_rule(means, name: str, value: float) -> np.ndarray:
    """The means as float64 [N, 3] for a geometric prune whose setting `name` has `value` (checked: finite, >= 0)."""
    why = finite_nonneg(value)
    if why:
        raise ValueError(f"{name} {why}")
    return np.asarray(means, np.float64).reshape(-1, 3)


def centres_in_frames(means: np.ndarray, cameras, margin: float, near: float = 0.01) -> np.ndarray:
    """[N] bool: the Gaussians whose centre some camera sees inside its image widened by `margin` times
    the image's width / height on each side, in front of its `near` plane (float64; the pinhole
    projection of reings.types.Camera: x = R mu + t, u = fx x / z + cx, v = fy y / z + cy)."""
    mu = _means_for_rule(means, "off_frame_margin", margin)
    inside = np.zeros(len(mu), bool)
    for cam in cameras:
        x = mu @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
        z = x[:, 2]
        front = z > near
        zs = np.where(front, z, 1.0)
        u = cam.K[0, 0] * x[:, 0] / zs + cam.K[0, 2]
        v = cam.K[1, 1] * x[:, 1] / zs + cam.K[1, 2]
        mw, mh = margin * cam.width, margin * cam.height
        inside |= front & (u >= -mw) & (u <= cam.width + mw) & (v >= -mh) & (v <= cam.height + mh)
    return inside


def away_from_cameras(means: np.ndarray, cameras, radius: float) -> np.ndarray:
    """[N] bool: the Gaussians whose centre lies at least `radius` from every camera's centre (float64;
    the centre of reings.types.Camera, -R^T t)."""
    mu = _means_for_rule(means, "near_prune_radius", radius)
    away = np.ones(len(mu), bool)
    for cam in cameras:
        d = mu - np.asarray(cam.center, np.float64)
        away &= np.einsum("ij,ij->i", d, d) >= radius * radius
    return away


def unseen_plan(seen: np.ndarray, n: int) -> RowPlan | None:
    """DensifyConfig.prune_unseen's row plan: keep the Gaussians some training pixel blends (`seen`:
    rendering.gaussian_importance over the training views > 0), or None when none or every one
    would go (never empty the model). No loss term of a fit reaches the unseen ones through a
    training view, so only the regularisers (whose gradients Adam normalises into full-size steps)
    and the virtual views move them; a test view between the training views can still see them
    (docs/method.md §11)."""
    seen = np.asarray(seen, bool)
    if seen.shape != (n,):
        raise ValueError(f"prune_unseen: mask of shape {seen.shape}, expected ({n},)")
    removed = int((~seen).sum())
    if not removed or removed == n:
        return None
    return index_plan(n, keep=seen)


def prune_unseen(state: TrainState, seen: np.ndarray) -> int:
    """`unseen_plan` applied to a TrainState. Returns how many went."""
    plan = unseen_plan(seen, len(state))
    if plan is None:
        return 0
    HeldRows(state).apply_rows(plan)
    return len(seen) - len(plan)


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
    """`densify_rows` on a TrainState (without prune_unseen, the off-frame prune and the near prune, which need
    the training views)."""
    return densify_rows(HeldRows(state), cfg, iteration, extent, rng)


def densify_rows(rows, cfg, iteration: int, extent: float, rng: np.random.Generator, importance=None,
                 cameras=None, near: float = 0.01) -> dict | None:
    """Run what `schedule` says is due after `iteration`, on `rows`: a Trainer (reings/backends/
    base.py) or reference_state.HeldRows of a TrainState. With dark_white_rules (DTU,
    reings.background) first the black / white rules; then `densify_plan` from the columns it reads
    (`read_columns`: on the device ~56 bytes per Gaussian cross the bus, not the state), applied by
    `apply_rows` (size pruning after size_prune_from); the opacity reset; with
    cfg.prune_unseen and `importance` (a callable giving Omega_G over the training views of the
    rows as they are then) the unseen Gaussians' prune; with cfg.off_frame_margin and the training
    `cameras`, the prune of the Gaussians whose centre no training view frames (`centres_in_frames`), with
    cfg.near_prune_radius the prune of those near a training camera (`away_from_cameras`): one read of the
    means, one surgery. Returns the counts or None."""
    dens, reset = schedule(cfg, iteration)
    out = {}
    if dens:
        params, stats = rows.read_columns(*decision_columns(cfg))
        if cfg.dark_white_rules:  # edits the accumulators (a decision input) and the opacities
            from types import SimpleNamespace

            from .background import dark_white_rules

            out["dark_white"] = dark_white_rules(SimpleNamespace(params=params, stats=stats))
            rows.write_params({"opacity_logits": params["opacity_logits"]})
        size_prune = cfg.size_prune_from is not None and iteration > cfg.size_prune_from
        plan, counts = densify_plan(params, stats, cfg, extent, rng, size_prune=size_prune)
        rows.apply_rows(plan, zero_stats=True)
        out.update(counts)
    if reset:
        rows.reset_opacity(_logit(0.01))
        out["opacity_reset"] = True
    if dens and cfg.prune_unseen and importance is not None:
        n = rows.n
        plan = unseen_plan(importance() > 0.0, n)
        if plan is not None:
            rows.apply_rows(plan)
        out.update(unseen=n - rows.n, n=rows.n)
    rules = {"off_frame": cfg.off_frame_margin, "near": cfg.near_prune_radius}
    if dens and cameras is not None and any(v is not None for v in rules.values()):
        n = rows.n
        params, _ = rows.read_columns(("means",))
        keep = np.ones(n, bool)
        for name, v in rules.items():
            if v is None:
                continue
            mask = (centres_in_frames(params["means"], cameras, v, near) if name == "off_frame"
                    else away_from_cameras(params["means"], cameras, v))
            out[name] = int((keep & ~mask).sum())  # the ones this rule adds
            keep &= mask
        plan = unseen_plan(keep, n)
        if plan is not None:
            rows.apply_rows(plan)
        else:  # none, or every one (never empty the model)
            out.update({name: 0 for name, v in rules.items() if v is not None})
        out["n"] = rows.n
    return out or None
# }}}
