"""`TrainState`: the optimised parameters, their Adam moments and per-Gaussian statistics, and the
ONE function that edits rows of all three together (`apply_index_op`, gsplat `strategy/ops.py`,
brush `map_momentum`).

Parameters are float32 arrays keyed by name (3DGS's split of the SH into DC and rest, so each has
its own lr):

    means [N,3]  quats [N,4] (wxyz)  log_scales [N,3]  opacity_logits [N]
    sh_dc [N,1,3]  sh_rest [N,K-1,3]   (K = 16 at SH degree 3; the active degree slices it)

`stats` holds per-Gaussian arrays that must follow row edits (densification accumulators,
`reings.densify`); new rows get zeros there, as they get zero Adam moments.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .backends.reference_state import apply_rows, sh_pack
from .optim.adam import AdamState
from .types import PARAM_NAMES, SH_COUNTS, Gaussians, RowPlan

__all__ = ["PARAM_NAMES", "TrainState", "apply_index_op", "index_plan", "reset_moments"]


@dataclass
class TrainState:
    params: dict[str, np.ndarray]  # name -> float32 [N, ...]
    adam: AdamState  # moments per param name, same shapes; step count per name
    stats: dict[str, np.ndarray] = field(default_factory=dict)  # name -> [N, ...] per-Gaussian statistics
    iteration: int = 0  # last completed iteration

    # {{{ construction and views
    @classmethod
    def from_gaussians(cls, g: Gaussians, sh_degree: int | None = None) -> "TrainState":
        """Parameters copied from `g`; SH padded with zeros (or truncated) to `sh_degree` (default:
        g's degree); zero moments."""
        k = SH_COUNTS[g.sh_degree if sh_degree is None else sh_degree]
        n = len(g)
        sh = np.zeros((n, k, 3), np.float32)
        kk = min(k, g.sh.shape[1])
        sh[:, :kk] = g.sh[:, :kk]
        params = {"means": g.means.copy(), "quats": g.quats.copy(), "log_scales": g.log_scales.copy(),
                  "opacity_logits": g.opacity_logits.copy(), "sh_dc": np.ascontiguousarray(sh[:, :1]),
                  "sh_rest": np.ascontiguousarray(sh[:, 1:])}
        return cls(params, AdamState.zeros_like(params))

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    @property
    def max_sh_degree(self) -> int:
        return SH_COUNTS.index(1 + self.params["sh_rest"].shape[1])

    def gaussians(self, sh_degree: int | None = None) -> Gaussians:
        """The current parameters as `Gaussians` (copies), SH truncated to the active `sh_degree`."""
        d = self.max_sh_degree if sh_degree is None else min(sh_degree, self.max_sh_degree)
        k = SH_COUNTS[d]
        p = self.params
        sh = sh_pack(p["sh_dc"], p["sh_rest"], k)
        return Gaussians(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], sh)

    def grads(self, v: Gaussians, fields=None) -> dict[str, np.ndarray]:
        """Split a `Gaussians` of raw-field gradients (from `render_vjp`) into per-param gradients;
        SH gradients of inactive degrees are zero.  `fields` restricts the result to some names
        (e.g. ("means",) after the hard-depth pass, so only that group is stepped)."""
        n, kmax = len(self), 1 + self.params["sh_rest"].shape[1]
        if len(v) != n:
            raise ValueError(f"gradient has {len(v)} rows, state has {n}")
        sh = np.zeros((n, kmax, 3), np.float32)
        sh[:, : v.sh.shape[1]] = v.sh
        out = {"means": v.means, "quats": v.quats, "log_scales": v.log_scales, "opacity_logits": v.opacity_logits,
               "sh_dc": sh[:, :1], "sh_rest": sh[:, 1:]}
        if fields is not None:
            out = {k: out[k] for k in fields}
        return out
    # }}}

    # {{{ checkpoint
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat dict for `np.savez` (params, moments, step counts, stats, iteration)."""
        d = {}
        for k, a in self.params.items():
            d[f"param/{k}"] = a
            d[f"exp_avg/{k}"] = self.adam.exp_avg[k]
            d[f"exp_avg_sq/{k}"] = self.adam.exp_avg_sq[k]
            d[f"step/{k}"] = np.int64(self.adam.step[k])
        for k, a in self.stats.items():
            d[f"stat/{k}"] = a
        d["iteration"] = np.int64(self.iteration)
        return d

    @classmethod
    def from_arrays(cls, d) -> "TrainState":
        """The state `to_arrays` flattened; ValueError saying what is wrong with a damaged one (a
        parameter missing, a shape or a row count that does not fit, a non-float array)."""
        names = [k.split("/", 1)[1] for k in d if k.startswith("param/")]
        if sorted(names) != sorted(PARAM_NAMES):
            raise ValueError(f"parameters {sorted(names)}, expected {sorted(PARAM_NAMES)}")
        params = {k: np.array(d[f"param/{k}"]) for k in names}
        adam = AdamState({k: np.array(d[f"exp_avg/{k}"]) for k in names},
                         {k: np.array(d[f"exp_avg_sq/{k}"]) for k in names},
                         {k: int(d[f"step/{k}"]) for k in names})
        stats = {k.split("/", 1)[1]: np.array(d[k]) for k in d if k.startswith("stat/")}
        _check_arrays(params, adam, stats)
        return cls(params, adam, stats, int(d["iteration"]))
    # }}}


# the shape of each parameter after its row count N (sh_rest: (K-1, 3) with K in SH_COUNTS)
_TAILS = {"means": (3,), "quats": (4,), "log_scales": (3,), "opacity_logits": (), "sh_dc": (1, 3)}


def _check_arrays(params: dict, adam: AdamState, stats: dict) -> None:
    """Every array of a state read back from a file: float32-compatible, one row count N, each
    parameter's shape, moments shaped like their parameter, statistics of N rows."""
    n = params["means"].shape[0] if params["means"].ndim else -1
    for k, a in params.items():
        tail = _TAILS.get(k)
        if tail is None:  # sh_rest
            fits = a.ndim == 3 and a.shape[2] == 3 and 1 + a.shape[1] in SH_COUNTS
        else:
            fits = a.shape[1:] == tail
        ok = a.dtype.kind == "f" and a.ndim >= 1 and a.shape[0] == n and fits
        if not ok:
            raise ValueError(f"parameter {k!r} has shape {a.shape} and dtype {a.dtype}, expected {n} rows of "
                             f"{tail if tail is not None else '(K-1, 3)'} floats")
        for what, m in (("exp_avg", adam.exp_avg[k]), ("exp_avg_sq", adam.exp_avg_sq[k])):
            if m.shape != a.shape or m.dtype.kind != "f":
                raise ValueError(f"{what} of {k!r} has shape {m.shape}, its parameter {a.shape}")
    for k, a in stats.items():
        if a.ndim < 1 or a.shape[0] != n:
            raise ValueError(f"statistic {k!r} has shape {a.shape}, expected {n} rows")


def _as_index(sel, n: int, what: str) -> np.ndarray:
    sel = np.asarray(sel)
    if sel.dtype == bool:
        if sel.shape != (n,):
            raise ValueError(f"{what}: boolean mask of shape {sel.shape}, expected ({n},)")
        return np.flatnonzero(sel)
    sel = sel.astype(np.int64).reshape(-1)
    if sel.size and (sel.min() < 0 or sel.max() >= n):
        raise IndexError(f"{what}: indices outside [0, {n})")
    return sel


def index_plan(n: int, keep=None, duplicate=None, append: dict | None = None, then_keep=None,
               names=PARAM_NAMES) -> RowPlan:
    """The RowPlan (reings.types) of `apply_index_op`'s arguments over a state of n rows with the
    parameters `names`; ValueError / IndexError naming a bad argument.

    New rows, in order:  [ rows[keep] ; rows[duplicate] ; append ]
      keep       bool mask [N] or indices: surviving rows, moments and stats kept (default: all)
      duplicate  indices into the *original* rows: copied parameters, zero moments and stats (clone)
      append     name -> new rows for every param (split children, new points): zero moments/stats
      then_keep  bool mask over those new rows: only its rows stay (a prune of the grown set in the
                 same pass: the rows of two calls, one copy of each array instead of two)"""
    ki = np.arange(n) if keep is None else _as_index(keep, n, "keep")
    di = np.zeros(0, np.int64) if duplicate is None else _as_index(duplicate, n, "duplicate")
    append = {k: np.asarray(a, np.float32) for k, a in (append or {}).items()}
    missing = [k for k in names if k not in append] if append else []
    if missing:
        raise ValueError(f"append: missing rows for {missing}")
    n_app = None
    for k, a in append.items():
        if k not in names:
            raise ValueError(f"append: unknown parameter {k!r}")
        if n_app is not None and a.shape[0] != n_app:
            raise ValueError("append: every parameter needs the same number of rows")
        n_app = a.shape[0]
    n_app = n_app or 0
    plan = RowPlan(np.concatenate([ki, di, np.full(n_app, -1, np.int64)]), len(ki), len(ki) + len(di), append)
    return plan if then_keep is None else plan.then_keep(then_keep)


def apply_index_op(state: TrainState, keep=None, duplicate=None, append: dict | None = None,
                   then_keep=None) -> None:
    """Edit the rows of params, Adam moments and stats together (in place on `state`'s dicts):
    the RowPlan of `index_plan` (its docstring says which rows come out), applied by the numpy
    twin of the device trainer's row gather (reference_state.apply_rows).

    Examples (N = 4):  keep=[T,F,T,T] -> 3 rows;  duplicate=[0,0] -> 6 rows, rows 4,5 copies of 0;
    split of row 1 into two children: keep=[T,F,T,T], append={name: 2 new rows} -> 5 rows.
    Adam step counts are untouched (3DGS keeps `state["step"]` when it concatenates tensors).
    """
    plan = index_plan(len(state), keep, duplicate, append, then_keep, names=tuple(state.params))
    apply_rows(state.params, state.adam.exp_avg, state.adam.exp_avg_sq, state.stats, plan)


def reset_moments(state: TrainState, name: str, rows=None) -> None:
    """Zero the Adam moments of parameter `name` (all rows, or a mask/indices), as 3DGS's
    `replace_tensor_to_optimizer` does at an opacity reset.  The step count is kept."""
    sel = slice(None) if rows is None else _as_index(rows, len(state), "rows")
    state.adam.exp_avg[name][sel] = 0.0
    state.adam.exp_avg_sq[name][sel] = 0.0
