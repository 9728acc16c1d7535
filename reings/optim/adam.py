"""Adam in numpy, in place, over named parameter groups (docs/perf_notes.md §6).

One group per parameter array (DNGaussian: "one Adam state per parameter tensor"), each with its own
learning rate, optional schedule and its **own step count**: DNGaussian steps the means and the
opacities after the hard- and soft-depth backward passes as well as after the photometric one
(docs/method.md §2.4), so their bias corrections run ahead of the other groups'.

The update is torch.optim.Adam's (the one 3DGS and DNGaussian use), per group with t = its count:

    m = b1*m + (1-b1)*g
    v = b2*v + (1-b2)*g*g
    p -= lr/(1-b1^t) * m / (sqrt(v)/sqrt(1-b2^t) + eps)

Everything is float32 and in place: `out=` everywhere and one preallocated scratch buffer (grown
geometrically, reused by every group), which is 1.4-2.9x faster than naive numpy expressions
(docs/perf_notes.md §6).  The update itself is `adam_update` (reings.backends.reference_state, the numpy
twin of kernels/adam.cl, shared with the training engines' trainers).  Parameters and moments live in dicts owned by `reings.state.TrainState`; row edits
(prune/clone/split) are a `reings.types.RowPlan` applied to all of them at once (`reings.state.apply_index_op`,
`Trainer.apply_rows`), which keeps them aligned.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Mapping

import numpy as np

from ..backends.reference_state import adam_update

__all__ = ["Adam", "AdamState", "adam_update"]


@dataclass
class AdamState:
    """First/second moments and step count per parameter name (the parameter's shape, float32)."""

    exp_avg: dict[str, np.ndarray] = field(default_factory=dict)
    exp_avg_sq: dict[str, np.ndarray] = field(default_factory=dict)
    step: dict[str, int] = field(default_factory=dict)

    @classmethod
    def zeros_like(cls, params: Mapping[str, np.ndarray]) -> "AdamState":
        return cls({k: np.zeros_like(p, dtype=np.float32) for k, p in params.items()},
                   {k: np.zeros_like(p, dtype=np.float32) for k, p in params.items()},
                   {k: 0 for k in params})


class Adam:
    """numpy Adam over the arrays of `params` (a dict, updated in place; keep passing the same dict).

    params: name -> float32 array; the dict is read at every step, so arrays replaced by
        a row edit (`apply_index_op`, `Trainer.apply_rows`) are picked up.
    lr: name -> learning rate (groups missing here are never stepped).
    state: the moments (default: zeros); shared with TrainState.
    schedules: name -> f(iteration) -> lr, applied by `update_learning_rate(iteration)`.
    """

    def __init__(self, params: dict[str, np.ndarray], lr: Mapping[str, float], state: AdamState | None = None,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-15,
                 schedules: Mapping[str, Callable[[int], float]] | None = None):
        unknown = [k for k in lr if k not in params]
        if unknown:
            raise ValueError(f"Adam: learning rates given for unknown parameters {unknown}; have {sorted(params)}")
        self.params = params
        self.lr = {k: float(v) for k, v in lr.items()}
        self.state = state if state is not None else AdamState.zeros_like(params)
        for k in self.lr:
            if k not in self.state.exp_avg:  # lazily created moments for a group added later
                self.state.exp_avg[k] = np.zeros_like(params[k], dtype=np.float32)
                self.state.exp_avg_sq[k] = np.zeros_like(params[k], dtype=np.float32)
                self.state.step[k] = 0
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.schedules = dict(schedules or {})
        self._scratch = np.empty(0, dtype=np.float32)  # flat, grown geometrically, shared by groups

    @property
    def groups(self) -> tuple[str, ...]:
        return tuple(self.lr)

    def update_learning_rate(self, iteration: int) -> None:
        """Set each scheduled group's lr to its schedule at `iteration` (3DGS `update_learning_rate`)."""
        for k, fn in self.schedules.items():
            self.lr[k] = float(fn(iteration))

    def _tmp(self, shape) -> np.ndarray:
        n = int(np.prod(shape))
        if self._scratch.size < n:
            self._scratch = np.empty(max(n, int(self._scratch.size * 1.5)), dtype=np.float32)
        return self._scratch[:n].reshape(shape)

    def step(self, grads: Mapping[str, np.ndarray], groups: Iterable[str] | None = None) -> None:
        """One Adam step of each group in `groups` (default: every group that has a gradient in
        `grads`, as torch skips parameters whose .grad is None).  Each stepped group's count += 1."""
        names = [k for k in grads if grads[k] is not None] if groups is None else list(groups)
        for k in names:
            if k not in self.lr:
                raise KeyError(f"Adam.step: {k!r} is not a parameter group ({self.groups})")
            if k not in grads or grads[k] is None:
                raise KeyError(f"Adam.step: no gradient for group {k!r}")
            self._step_one(k, grads[k])

    def _step_one(self, k: str, g) -> None:
        p = self.params[k]
        m, v = self.state.exp_avg[k], self.state.exp_avg_sq[k]
        g = np.asarray(g, dtype=np.float32)
        if g.shape != p.shape:
            raise ValueError(f"Adam.step: gradient of {k!r} has shape {g.shape}, parameter has {p.shape}")
        if m.shape != p.shape or v.shape != p.shape:
            raise RuntimeError(f"Adam: moments of {k!r} {m.shape} are out of step with the parameter {p.shape}; "
                               "edit rows with reings.state.apply_index_op (a RowPlan)")
        if p.size == 0:
            self.state.step[k] += 1
            return
        t = self.state.step[k] + 1
        self.state.step[k] = t
        adam_update(p, m, v, g, self.lr[k], t, self.beta1, self.beta2, self.eps, self._tmp(p.shape))
