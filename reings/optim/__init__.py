"""Optimizer: numpy Adam with per-group steps (`adam`), lr schedules (`schedules`), and
`make_optimizer`, which builds the Adam of a `TrainState` from an `OptimConfig`."""
from __future__ import annotations

from .adam import Adam, AdamState
from .schedules import depth_smooth_weight_at, expon_lr, held_expon_lr, position_lr, sh_degree_at


def make_optimizer(state, optim_cfg, extent: float) -> Adam:
    """Adam over a TrainState's params with the lrs of `optim_cfg` (an OptimConfig); the means get
    the (held) exponential schedule scaled by `extent`.  Call `update_learning_rate(iteration)`
    once per iteration before stepping."""
    c = optim_cfg
    lr = {"means": c.position_lr_init * extent, "quats": c.rotation_lr, "log_scales": c.scaling_lr,
          "opacity_logits": c.opacity_lr, "sh_dc": c.sh_dc_lr, "sh_rest": c.sh_rest_lr}
    lr = {k: v for k, v in lr.items() if k in state.params}
    return Adam(state.params, lr, state=state.adam, betas=(c.beta1, c.beta2), eps=c.eps,
                schedules={"means": lambda it: position_lr(it, c, extent)})


__all__ = ["Adam", "AdamState", "make_optimizer", "expon_lr", "held_expon_lr", "position_lr", "sh_degree_at",
           "depth_smooth_weight_at"]
