"""numpy references of the stages that update the training state, one function per kernel:

    sh_pack             (no kernel: project.cl reads   the projection's [N,k,3] SH at k active coefficients
                        sh_dc and sh_rest in place)    (the host trainer's, TrainState.gaussians)
    adam_update         kernels/adam.cl adam_step     one float32 Adam update, numpy's exact op sequence
    ndc_grad_norm,      kernels/densify_accumulate.cl 3DGS `add_densification_stats` for one view
    densify_accumulate
    grad_add            kernels/project.cl            the gradients of a second backward added in place
                        project_bwd (grad_acc 1)
    opacity_decay_      kernels/regularize.cl         logits <- logit(f sigmoid(logits)) in place, the
                        opacity_decay                 float64 twin reference_view_warp.opacity_decay
                                                      rounded to float32
    gather_rows,        kernels/gather_rows.cl        the rows of a new row set (types.RowPlan): every
    apply_rows                                        parameter, moment and statistic array gathered
    opacity_cap_                                      (the densification's surgery, apply_index_op);
                                                      3DGS's opacity reset, logits <- min(logits, cap)

The state's arrays are named in `reings.types` (PARAM_NAMES; ACCUM, COUNT, RADII). These are the
arithmetic that both training engines share: the host trainer (reings/backends/host_trainer.py)
calls them, the engine re-exports them (`reings.optim.adam.adam_update`, `reings.densify.accumulate`),
and the kernels follow their float32 operation order (tests/test_adam_kernel.py,
tests/test_device_fit.py: bit-identical on PoCL). Unlike the render and loss references these run
in float32 where the engine keeps float32 state: they define what the float32 state becomes.
"""
from __future__ import annotations

import numpy as np

from ..types import ACCUM, COUNT, RADII, STAT_DTYPES, RowPlan


def sh_pack(sh_dc: np.ndarray, sh_rest: np.ndarray, k: int) -> np.ndarray:
    """[N,1,3] sh_dc and the first k-1 rows of [N,kmax-1,3] sh_rest -> [N,k,3] (a new array)."""
    return np.concatenate([sh_dc, sh_rest[:, : k - 1]], axis=1)


def adam_update(p: np.ndarray, m: np.ndarray, v: np.ndarray, g: np.ndarray, lr: float, t: int,
                b1: float, b2: float, eps: float, tmp: np.ndarray) -> None:
    """One in-place float32 Adam update of (p, m, v) with gradient g at step count t (>= 1); tmp is
    scratch of p's shape.  The exact float32 operation sequence that `kernels/adam.cl` mirrors
    (the 1/sqrt(bc2) product is a float64 scalar, so numpy computes that one product in float64).
    Used by reings.optim.Adam, the host trainer and the device trainer's numpy Adam location."""
    # m = b1*m + (1-b1)*g
    np.multiply(m, b1, out=m)
    np.multiply(g, 1.0 - b1, out=tmp)
    np.add(m, tmp, out=m)
    # v = b2*v + (1-b2)*g^2
    np.multiply(v, b2, out=v)
    np.multiply(g, g, out=tmp)
    np.multiply(tmp, 1.0 - b2, out=tmp)
    np.add(v, tmp, out=v)
    # p -= lr/bc1 * m / (sqrt(v)/sqrt(bc2) + eps)
    bc1 = 1.0 - b1 ** t
    bc2 = 1.0 - b2 ** t
    np.sqrt(v, out=tmp)
    np.multiply(tmp, 1.0 / np.sqrt(bc2), out=tmp)
    np.add(tmp, eps, out=tmp)
    np.divide(m, tmp, out=tmp)
    np.multiply(tmp, -lr / bc1, out=tmp)
    np.add(p, tmp, out=p)


def zero_stats(n: int) -> dict[str, np.ndarray]:
    """Fresh densification statistics for n Gaussians (zeros of STAT_DTYPES)."""
    return {k: np.zeros(n, dt) for k, dt in STAT_DTYPES.items()}


def ndc_grad_norm(v_means2d: np.ndarray, width: int, height: int) -> np.ndarray:
    """[N,2] pixel-space dL/d means2d -> [N] norms in 3DGS's NDC-scaled units (x W/2, y H/2)."""
    v = np.asarray(v_means2d, np.float64)
    x, y = v[:, 0] * (0.5 * width), v[:, 1] * (0.5 * height)
    # sqrt(x x + y y) in float64, as kernels/densify.h computes it (each operation IEEE-rounded: the same bits; the
    # squares of float32 values times W/2, H/2 neither overflow nor underflow in float64)
    return np.sqrt(x * x + y * y).astype(np.float32)


def densify_accumulate(stats: dict, grad_norms: np.ndarray, visible: np.ndarray,
                       radii: np.ndarray | None = None) -> None:
    """3DGS `add_densification_stats` for one view, in place on `stats` (ACCUM, COUNT, RADII): for
    the visible Gaussians (radius > 0), add the NDC gradient norm and count the view; track the
    max screen radius."""
    n = len(stats[ACCUM])
    vis = np.asarray(visible, bool)
    g = np.asarray(grad_norms, np.float32)
    if vis.shape != (n,) or g.shape != (n,):
        raise ValueError(f"accumulate: grad_norms {g.shape} and visible {vis.shape} must be ({n},)")
    stats[ACCUM][vis] += g[vis]
    stats[COUNT][vis] += 1
    if radii is not None:
        r = np.asarray(radii, np.float32)
        np.maximum(stats[RADII], np.where(vis, r, 0.0), out=stats[RADII])


def grad_add(dst: np.ndarray, src: np.ndarray) -> None:
    """dst += src in float32, in place (project.cl project_bwd with grad_acc 1: one IEEE add per element,
    same bits)."""
    if dst.shape != src.shape:
        raise ValueError(f"grad_add: shapes {dst.shape} and {src.shape} differ")
    np.add(dst, np.asarray(src, np.float32), out=dst)


def opacity_decay_(logits: np.ndarray, factor: float) -> None:
    """The opacity decay of the float32 state, in place: logits <- float32(logit(factor *
    sigmoid(logits))) computed in float64 (reference_view_warp.opacity_decay; kernels/regularize.cl
    opacity_decay computes the same in double where the device has cl_khr_fp64)."""
    from .reference_view_warp import opacity_decay

    with np.errstate(invalid="ignore"):  # NaN logits stay NaN
        logits[...] = opacity_decay(logits, factor).astype(np.float32)



def gather_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """out[r] = a[idx[r]], zeros where idx[r] < 0 (kernels/gather_rows.cl: the bits copied); a new
    C-contiguous array of a's dtype."""
    idx = np.asarray(idx, np.int64)
    out = np.zeros((len(idx),) + a.shape[1:], a.dtype)
    has = idx >= 0
    out[has] = a[idx[has]]
    return out


def apply_rows(params: dict, exp_avg: dict, exp_avg_sq: dict, stats: dict, plan: RowPlan,
               zero_stats: bool = False) -> None:
    """The new row set `plan` (types.RowPlan) of a training state's arrays, in place on the dicts
    (each array replaced by a fresh one): parameters gathered from plan.src, then plan.fresh written
    from row plan.fresh_start; moments and statistics gathered for the plan.n_kept kept rows, zero
    after (every statistic zero with `zero_stats`). The twin of the device trainer's apply_rows."""
    n_old = len(params["means"])
    plan.check(n_old, {k: p.shape[1:] for k, p in params.items()})
    src = np.asarray(plan.src, np.int64)
    kept = np.concatenate([src[:plan.n_kept], np.full(len(src) - plan.n_kept, -1, np.int64)])
    for k, p in params.items():
        out = gather_rows(p, src)
        if k in plan.fresh:
            out[plan.fresh_start:] = np.asarray(plan.fresh[k], np.float32).reshape((-1,) + p.shape[1:])
        params[k] = out
        exp_avg[k] = gather_rows(exp_avg[k], kept)
        exp_avg_sq[k] = gather_rows(exp_avg_sq[k], kept)
    for k, a in stats.items():
        stats[k] = np.zeros((len(src),) + a.shape[1:], a.dtype) if zero_stats else gather_rows(a, kept)


def opacity_cap_(logits: np.ndarray, cap_logit: float) -> None:
    """3DGS's opacity reset on the float32 logits, in place: logits <- min(logits, float32(cap))
    (the trainer also zeroes their Adam moments)."""
    np.minimum(logits, np.float32(cap_logit), out=logits)


class HeldRows:
    """The Trainer contract's row edits (reings/backends/base.py: `n`, `read_columns`,
    `write_params`, `apply_rows`, `reset_opacity`) on a held TrainState-like `self.state` (params,
    adam.exp_avg / exp_avg_sq, stats dicts), in numpy, in place: the host trainer's, and the
    engine's for a bare TrainState (reings.densify.maybe_densify). The device trainer does the same
    on its buffers."""

    def __init__(self, state=None):
        self.state = state

    @property
    def n(self) -> int:
        """The held state's number of Gaussians."""
        return len(self.state.params["means"])

    def apply_rows(self, plan: RowPlan, zero_stats: bool = False) -> None:
        st = self.state
        apply_rows(st.params, st.adam.exp_avg, st.adam.exp_avg_sq, st.stats, plan, zero_stats)

    def read_columns(self, params, stats=()) -> tuple[dict, dict]:
        """The held arrays themselves (no copy: an edit of them is an edit of the state, which
        `write_params` then has nothing to do for); missing statistics start at zero."""
        if any(k not in self.state.stats for k in stats):
            self.state.stats.update({k: v for k, v in zero_stats(self.n).items() if k not in self.state.stats})
        return {k: self.state.params[k] for k in params}, {k: self.state.stats[k] for k in stats}

    def write_params(self, arrays: dict) -> None:
        for k, a in arrays.items():
            dst = self.state.params[k]
            if a is not dst:
                if np.shape(a) != dst.shape:
                    raise ValueError(f"write_params: {k!r} of shape {np.shape(a)}, expected {dst.shape}")
                dst[...] = a

    def reset_opacity(self, cap_logit: float) -> None:
        st = self.state
        opacity_cap_(st.params["opacity_logits"], cap_logit)
        st.adam.exp_avg["opacity_logits"][...] = 0.0
        st.adam.exp_avg_sq["opacity_logits"][...] = 0.0
