"""Training configuration as dataclasses, plus named presets.

Each field's trailing comment is its help text (the CLI builds argparse from these dataclasses).
Learning rates of the means are multiplied by the scene extent (`spatial_lr_scale` in 3DGS) where
the optimizer is built (`reings.optim.make_optimizer`), not here.

Presets:
    "3dgs"        original 3DGS (METHOD.md §5.6), commit 82bc469 defaults
    "dngaussian"  DNGaussian LLFF recipe (METHOD.md §2.2-2.4), SH colour instead of the neural field
    "dngaussian_dtu"  DNGaussian DTU recipe (METHOD.md §2.2 right column)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace


@dataclass(frozen=True)
class OptimConfig:
    position_lr_init: float = 0.00016  # lr of the means at the schedule start, times the scene extent
    position_lr_final: float = 0.0000016  # lr of the means at the schedule end, times the scene extent
    position_lr_delay_mult: float = 0.01  # 3DGS delay multiplier (inactive while position_lr_delay_steps = 0)
    position_lr_delay_steps: int = 0  # 3DGS reverse-cosine warm-up length (0 = off, as in 3DGS and DNGaussian)
    position_lr_start: int = 0  # iterations the means' lr is held at init before decaying (DNGaussian: 500)
    position_lr_max_steps: int = 30_000  # length of the log-linear decay, counted from position_lr_start
    sh_dc_lr: float = 0.0025  # lr of the SH DC coefficients (f_dc)
    sh_rest_lr: float = 0.0025 / 20.0  # lr of the higher SH coefficients (f_rest)
    opacity_lr: float = 0.05  # lr of the opacity logits
    scaling_lr: float = 0.005  # lr of the log-scales
    rotation_lr: float = 0.001  # lr of the quaternions
    beta1: float = 0.9  # Adam beta1
    beta2: float = 0.999  # Adam beta2
    eps: float = 1e-15  # Adam epsilon (3DGS: 1e-15)


@dataclass(frozen=True)
class LossConfig:
    photometric_form: str = "3dgs"  # "3dgs": (1-l)*L1 + l*(1-SSIM); "dngaussian": L1 + l*(1-SSIM)
    lambda_dssim: float = 0.2  # the SSIM weight l (DNGaussian: 0.2 LLFF, 0.6 DTU)
    hard_depth: bool = False  # DNGaussian hard depth term: opacity fixed, gradient to the means only
    hard_depth_from: int = 1  # first iteration of the hard depth term
    hard_depth_opacity: float = 0.95  # the fixed opacity of the hard-depth render (ReInGS: 0.99)
    soft_depth: bool = False  # DNGaussian soft depth term: real opacities, gradient to opacities only
    soft_depth_from: int = 1001  # first iteration of the soft depth term
    soft_depth_ema_gate: float | None = None  # DTU: soft depth only while EMA(0.9) of the hard loss < this
    depth_patch_range: tuple[int, int] = (5, 17)  # patch size drawn uniformly in [lo, hi], anew per term
    depth_margin: float = 0.00025  # margin L2: errors with |diff| <= margin are ignored ("error_tolerance")
    depth_w_local: float = 0.1  # weight of the local (per-patch std) normalised depth term
    depth_w_global: float = 1.0  # weight of the global (whole-image std) normalised depth term
    depth_smooth_weight: float = 0.0  # edge-aware depth smoothness weight, in both depth passes (DNGaussian LLFF: 0.1)
    depth_smooth_from: int = 3001  # first iteration of the smoothness term (DNGaussian: iteration > 3000)
    shape_pena: float = 0.0  # weight of mean(max scale / min scale)
    scale_pena: float = 0.0  # weight of mean(max scale^2)
    opa_pena: float = 0.0  # weight of 1 - mean(o^2 | o>0.2) + mean((1-o)^2 | o<0.2)


@dataclass(frozen=True)
class DensifyConfig:
    densify_from: int = 500  # densify only at iterations > this
    densify_until: int = 15_000  # ... and < this (3DGS/DNGaussian `iteration < densify_until_iter`)
    densify_interval: int = 100  # densify every this many iterations
    grad_threshold: float = 0.0002  # mean NDC-scaled screen gradient norm that triggers clone/split
    percent_dense: float = 0.01  # clone if max scale <= this * extent, else split
    split_opacity_thresh: float | None = None  # DNGaussian: clone/split only Gaussians with opacity > this
    split_n: int = 2  # samples per split Gaussian (scale divided by 0.8 * split_n)
    prune_opacity: float = 0.005  # prune Gaussians with opacity below this at each densification
    opacity_reset_interval: int | None = 3000  # reset opacities to min(o, 0.01) every this many its (None = off)
    size_prune_from: int | None = 3000  # from this iteration (> opacity reset interval in 3DGS) also prune big ones (None = off)
    max_screen_size: float | None = 20.0  # prune if max screen radius (px) exceeds this (with size_prune_from)
    max_world_size: float | None = 0.1  # prune if max scale exceeds this * extent (with size_prune_from)
    max_gaussians: int | None = None  # optional cap on the Gaussian count (highest-gradient candidates win)
    clean_views: bool = False  # drop Gaussians no training view sees, at the first iteration (DNGaussian)


@dataclass(frozen=True)
class TrainConfig:
    iterations: int = 30_000  # training iterations
    seed: int = 0  # seed of every random draw (view order, patch sizes, split samples)
    sh_degree: int = 3  # maximum SH degree
    sh_degree_interval: int = 1000  # raise the active SH degree by 1 every this many iterations
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)  # background colour
    near: float = 0.01  # near plane of the renders
    optim: OptimConfig = field(default_factory=OptimConfig)  # optimizer and learning rates
    loss: LossConfig = field(default_factory=LossConfig)  # losses and weights
    densify: DensifyConfig = field(default_factory=DensifyConfig)  # densification and pruning

    def to_dict(self) -> dict:
        return asdict(self)


def _dngaussian_llff() -> TrainConfig:
    return TrainConfig(
        iterations=6000,
        optim=OptimConfig(position_lr_init=0.016, position_lr_final=0.00016, position_lr_start=500,
                          position_lr_max_steps=5500, sh_dc_lr=0.0025, sh_rest_lr=0.000125,
                          opacity_lr=0.05, scaling_lr=0.003, rotation_lr=0.001),
        loss=LossConfig(photometric_form="dngaussian", lambda_dssim=0.2, hard_depth=True, hard_depth_from=1,
                        hard_depth_opacity=0.95, soft_depth=True, soft_depth_from=1001, depth_patch_range=(5, 17),
                        depth_margin=0.00025, depth_smooth_weight=0.1, depth_smooth_from=3001,
                        shape_pena=0.002, scale_pena=0.001, opa_pena=0.001),
        densify=DensifyConfig(densify_from=500, densify_until=6000, densify_interval=100, grad_threshold=0.0013,
                              percent_dense=0.01, split_opacity_thresh=0.1, prune_opacity=0.01,
                              opacity_reset_interval=None, size_prune_from=None, max_screen_size=None,
                              max_world_size=None, clean_views=True),
    )


def _dngaussian_dtu() -> TrainConfig:
    c = _dngaussian_llff()
    return replace(
        c,
        optim=replace(c.optim, position_lr_init=0.0016, position_lr_final=0.000016),
        loss=replace(c.loss, lambda_dssim=0.6, depth_patch_range=(17, 53), depth_margin=0.01, shape_pena=0.005,
                     scale_pena=0.005, opa_pena=0.001, soft_depth_ema_gate=0.1,
                     depth_smooth_weight=0.0),
        densify=replace(c.densify, grad_threshold=0.001, percent_dense=0.1),
    )


PRESETS: dict[str, TrainConfig] = {
    "3dgs": TrainConfig(),
    "dngaussian": _dngaussian_llff(),
    "dngaussian_dtu": _dngaussian_dtu(),
}
PRESET_HELP: dict[str, str] = {
    "3dgs": "original 3DGS (METHOD.md §5.6): 30k its, (1-0.2)L1 + 0.2 D-SSIM, opacity reset",
    "dngaussian": "DNGaussian LLFF (METHOD.md §2.2): 6k its, hard+soft depth, SH colour",
    "dngaussian_dtu": "DNGaussian DTU (METHOD.md §2.2)",
}


def preset(name: str) -> TrainConfig:
    """The TrainConfig of a named preset (ValueError lists the names)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
    return PRESETS[name]
