"""Schedules: small pure functions of the step (learning rates, the active SH degree, the depth
smoothness weight).

`expon_lr` is 3DGS's `get_expon_lr_func` (log-linear interpolation from lr_init to lr_final over
max_steps, optional reverse-cosine delay).  DNGaussian calls it with `max(iteration - 500, 0)`
(`position_lr_start`), i.e. the lr is held at lr_init for 500 iterations and then decays over
`max_steps` iterations; `position_lr` is that composition.
"""
from __future__ import annotations

import math


def expon_lr(step: int, lr_init: float, lr_final: float, max_steps: int,
             delay_steps: int = 0, delay_mult: float = 1.0) -> float:
    """3DGS `get_expon_lr_func(lr_init, lr_final, delay_steps, delay_mult, max_steps)(step)`."""
    if step < 0 or (lr_init == 0.0 and lr_final == 0.0):
        return 0.0  # 3DGS: a disabled parameter
    if delay_steps > 0:
        delay_rate = delay_mult + (1 - delay_mult) * math.sin(0.5 * math.pi * min(max(step / delay_steps, 0.0), 1.0))
    else:
        delay_rate = 1.0
    t = min(max(step / max_steps, 0.0), 1.0)
    return delay_rate * math.exp(math.log(lr_init) * (1 - t) + math.log(lr_final) * t)


def held_expon_lr(iteration: int, lr_init: float, lr_final: float, max_steps: int, start: int = 0,
                  delay_steps: int = 0, delay_mult: float = 1.0) -> float:
    """DNGaussian's position schedule: `expon_lr(max(iteration - start, 0), ...)`.

    Held at lr_init for iterations <= start, then log-linear down to lr_final at start + max_steps
    and constant after.  With start = 0 this is the 3DGS schedule.
    """
    return expon_lr(max(iteration - start, 0), lr_init, lr_final, max_steps, delay_steps, delay_mult)


def position_lr(iteration: int, optim_cfg, extent: float) -> float:
    """The means' lr at `iteration` for an `OptimConfig` (lrs are multiplied by the scene extent)."""
    c = optim_cfg
    return held_expon_lr(iteration, c.position_lr_init * extent, c.position_lr_final * extent,
                         c.position_lr_max_steps, c.position_lr_start, c.position_lr_delay_steps,
                         c.position_lr_delay_mult)


def sh_degree_at(iteration: int, max_degree: int, interval: int = 1000) -> int:
    """Active SH degree: 3DGS raises it by one every `interval` iterations (at 1000, 2000, ...)."""
    return min(max_degree, max(iteration, 0) // interval)


def depth_smooth_weight_at(loss_config, iteration: int) -> float:
    """The depth_smooth term's weight at `iteration` for a LossConfig: depth_smooth_weight from
    depth_smooth_from on (DNGaussian LLFF: iterations > 3000), 0 before. The one rule of the fit
    loop (reings/train.py)."""
    L = loss_config
    return float(L.depth_smooth_weight) if L.depth_smooth_weight and iteration >= L.depth_smooth_from else 0.0
