"""Configuration as typed, frozen dataclasses, each field documented once.

Two families live here:

    TrainConfig (OptimConfig, LossConfig, DensifyConfig)
        the recipe of one fit (`reings.train.fit`); named recipes in PRESETS:
        "3dgs" (original 3DGS, commit 82bc469 defaults), "dngaussian" (DNGaussian's LLFF recipe,
        SH colour instead of its neural colour field), "dngaussian_dtu" (its DTU recipe).
    RunConfig (ReInGSConfig, OutputConfig)
        everything `reings run` / `reings.run` needs: data, method and ablation switches, views,
        seed, device, preset, iterations per fitting stage, the ReInGS knobs, the depth prior,
        outputs, and the TrainConfig overrides a user sets (SH degree, Gaussian cap, smoothness).

Every field is declared with `opt(default, "help")`: the help text sits in the field's metadata,
and the command line (`reings.cli` generates `reings run` / `reings eval` from RunConfig), the
comments of the `config.toml` a run writes (`to_toml`) and `field_help` all read it there.
RunConfig and its sections check and normalise their values when built (`__post_init__`), so a
config from Python, from the command line or from a TOML file fails the same way: a ValueError
naming the field. Learning rates of the means are multiplied by the scene extent
(`spatial_lr_scale` in 3DGS) where the optimizer is built (`reings.optim.make_optimizer`).

This module imports the standard library only (the CLI starts from it).
"""
from __future__ import annotations

import math
import numbers
import os
import typing
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace


def opt(default=MISSING, help: str = "", *, factory=None, cli: str | None = None, choices=None,
        check=None, parse=None, metavar: str | None = None):
    """A dataclass field with its documentation and command-line facts in the metadata.

    help: the one description of the field (CLI help, TOML comment). cli: the option name when it
    is not `--<field-name>`. choices: the allowed values. check: f(value) -> None or the reason the
    value is refused ("must be >= 1, got 0"), applied by the CLI and on construction. parse:
    f(text) -> value for the CLI instead of the type's own parser."""
    md = {"help": help, "cli": cli, "choices": None if choices is None else tuple(choices),
          "check": check, "parse": parse, "metavar": metavar}
    if factory is not None:
        return field(default_factory=factory, metadata=md)
    return field(default=default, metadata=md)


def field_help(cls, name: str) -> str:
    """The documentation of field `name` of dataclass `cls`."""
    for f in fields(cls):
        if f.name == name:
            return f.metadata.get("help", "")
    raise KeyError(f"{cls.__name__} has no field {name!r}")


# {{{ value checks (None = fine, else the reason)

def at_least(lo):
    return lambda v: None if v >= lo else f"must be >= {lo}, got {v}"


def finite_nonneg(v):
    return None if (v >= 0.0 and v != math.inf) else f"must be a finite number >= 0, got {v}"  # refuses nan


def count_at_least_1(v):
    """An integer >= 1 (numpy's too; not a bool): LossConfig / RunConfig.view_warp_every, as fit() checks it."""
    ok = isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 1
    return None if ok else f"must be an integer >= 1, got {v!r}"


def fraction_open_closed(v):
    return None if 0.0 < v <= 1.0 else f"must be in (0, 1], got {v}"


def prune_fraction(v):
    return None if 0.0 <= v < 1.0 else f"must be a fraction in [0, 1) (0 = off), got {v}"


def positive_all(v):
    bad = [x for x in v if x < 1]
    return f"must be >= 1, got {bad[0]}" if bad else None


def _checked_list(parts, convert, wrong: str, check) -> tuple:
    """The comma-separated `parts` converted one by one (ValueError `wrong` + the part when one does
    not convert), then `check`ed as a whole (ValueError with its reason)."""
    vals = []
    for p in parts:
        try:
            vals.append(convert(p))
        except ValueError:
            raise ValueError(f"{wrong}, got {p!r}") from None
    bad = check(vals)
    if bad:
        raise ValueError(bad)
    return tuple(vals)


def parse_iterations(text: str):
    """N, or A,B,C (one count per reings fitting stage: coarse, fine, final); positive integers."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (1, 3):
        raise ValueError(f"expected N or A,B,C (one count per reings stage: coarse, fine, final), got {text!r}")
    return _checked_list(parts, int, "expected an integer", positive_all)


def stage_value(values, stage: str | None) -> float:
    """One value of a per-stage setting: the one value given, or of three (one per reings fitting stage,
    FIT_STAGES order) the stage's; the baselines' single fit, and stage none, take the last."""
    stages = FIT_STAGES["reings"]
    if len(values) == 1:
        return float(values[0])
    return float(values[stages.index(stage)] if stage in stages else values[-1])


def _per_stage(text: str, one: str, what: str, convert, wrong: str, check) -> tuple:
    """A per-stage option's text: `one` value or A,B,C (one `what` per reings fitting stage), each converted
    (`wrong` when one does not) and the whole `check`ed (_checked_list)."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (1, 3):
        raise ValueError(f"expected {one} or A,B,C (one {what} per reings stage: coarse, fine, final), got {text!r}")
    return _checked_list(parts, convert, wrong, check)


def lambda_dssim_values(v):
    """None, or why SSIM weights are refused: one or three (one per reings fitting stage) numbers in [0, 10]."""
    if len(v) not in (1, 3):
        return f"must be one weight or three (reings: coarse, fine, final), got {len(v)}"
    bad = [x for x in v if not 0 <= x <= 10]  # refuses nan
    return f"must lie in [0, 10], got {bad[0]}" if bad else None


def parse_lambda_dssim(text: str):
    """L, or A,B,C (one SSIM weight per reings fitting stage: coarse, fine, final); numbers in [0, 10]."""
    return _per_stage(text, "L", "SSIM weight", float, "expected a number", lambda_dssim_values)


def fit_scale_values(v):
    """None, or why fit scales are refused: one or three (one per reings fitting stage) of 1, 2, 4."""
    if len(v) not in (1, 3):
        return f"must be one scale or three (reings: coarse, fine, final), got {len(v)}"
    bad = [x for x in v if x not in (1, 2, 4)]
    return f"must be 1, 2 or 4, got {bad[0]}" if bad else None


def parse_fit_scale(text: str):
    """S, or A,B,C (one resolution divisor per reings fitting stage: coarse, fine, final): 1, 2 or 4."""
    return _per_stage(text, "S", "scale", int, "expected an integer", fit_scale_values)


def fit_scale_share_values(v):
    """None, or why fit-scale shares are refused: one or three (one per reings fitting stage) numbers in (0, 1]."""
    if len(v) not in (1, 3):
        return f"must be one share or three (reings: coarse, fine, final), got {len(v)}"
    bad = [x for x in v if not 0 < x <= 1]  # also NaN
    return f"must lie in (0, 1], got {bad[0]}" if bad else None


def parse_fit_scale_share(text: str):
    """F, or A,B,C (the share of each reings fit's iterations at its fit scale: coarse, fine, final): in (0, 1]."""
    return _per_stage(text, "F", "share", float, "expected a number", fit_scale_share_values)


def blur_sigmas(v):
    """None, or why a tuple of blur sigmas (pixels) is refused: each a finite number > 0 (the sharp
    level, sigma 0, is always taken: a 0 here would count it twice)."""
    bad = [x for x in v if not (x > 0.0 and x != math.inf)]  # refuses nan
    return (f"must hold finite numbers > 0 (the sharp level is always taken), got {bad[0]}" if bad
            else None)


def parse_blur_sigmas(text: str):
    """SIGMA[,SIGMA...] (numbers > 0, in pixels), or none / an empty text: no level."""
    t = str(text).strip()
    if t.lower() in ("", "none"):
        return ()
    return _checked_list(t.split(","), float, "expected comma-separated numbers (sigmas in pixels) or none",
                         blur_sigmas)
# }}}


# {{{ TrainConfig: the recipe of one fit

@dataclass(frozen=True)
class OptimConfig:
    """Optimizer and learning rates."""

    position_lr_init: float = opt(0.00016, "lr of the means at the schedule start, times the scene extent")
    position_lr_final: float = opt(0.0000016, "lr of the means at the schedule end, times the scene extent")
    position_lr_delay_mult: float = opt(0.01, "3DGS delay multiplier (inactive while position_lr_delay_steps = 0)")
    position_lr_delay_steps: int = opt(0, "3DGS reverse-cosine warm-up length (0 = off, as in 3DGS and DNGaussian)")
    position_lr_start: int = opt(0, "iterations the means' lr is held at init before decaying (DNGaussian: 500)")
    position_lr_max_steps: int = opt(30_000, "length of the log-linear decay, counted from position_lr_start")
    sh_dc_lr: float = opt(0.0025, "lr of the SH DC coefficients (f_dc)")
    sh_rest_lr: float = opt(0.0025 / 20.0, "lr of the higher SH coefficients (f_rest)")
    opacity_lr: float = opt(0.05, "lr of the opacity logits")
    scaling_lr: float = opt(0.005, "lr of the log-scales")
    rotation_lr: float = opt(0.001, "lr of the quaternions")
    beta1: float = opt(0.9, "Adam beta1")
    beta2: float = opt(0.999, "Adam beta2")
    eps: float = opt(1e-15, "Adam epsilon (3DGS: 1e-15)")


@dataclass(frozen=True)
class LossConfig:
    """Losses and their weights."""

    photometric_form: str = opt("3dgs", '"3dgs": (1-l)*L1 + l*(1-SSIM); "dngaussian": L1 + l*(1-SSIM)')
    lambda_dssim: float = opt(0.2, "the SSIM weight l (DNGaussian: 0.2 LLFF, 0.6 DTU)")
    hard_depth: bool = opt(False, "DNGaussian hard depth term: opacity fixed, gradient to the means only")
    hard_depth_from: int = opt(1, "first iteration of the hard depth term")
    hard_depth_opacity: float = opt(0.95, "the fixed opacity of the hard-depth render (ReInGS: 0.99)")
    hard_depth_scale: int = opt(1, "the hard depth pass at 1/scale of the training resolution (speed, issue 15): "
                                   "its camera's image size and intrinsics divided by scale (the last rows and "
                                   "columns that do not fill a block dropped), the depth prior and its weights "
                                   "averaged over scale x scale blocks; the patch sizes stay in pixels (the hard "
                                   "loss that soft_depth_ema_gate reads is then the small pass's); 1 = full "
                                   "resolution (DNGaussian)",
                                check=lambda v: None if v in (1, 2, 4) else f"must be 1, 2 or 4, got {v}")
    hard_depth_patches: str = opt("pixels", "the hard depth loss's patch sizes at hard_depth_scale > 1: 'pixels' "
                                            "(as drawn, so a patch covers scale^2 times the scene area), 'area' "
                                            "(each drawn size divided by the scale, rounded up: the full-resolution "
                                            "patch's area)", choices=("pixels", "area"))
    soft_depth: bool = opt(False, "DNGaussian soft depth term: real opacities, gradient to opacities only")
    soft_depth_from: int = opt(1001, "first iteration of the soft depth term")
    soft_depth_shared: bool = opt(False, "speed, changes the optimizer's steps: the soft depth term reuses the "
                                         "photometric pass's render (one render fewer per iteration) and its "
                                         "opacity gradient joins the photometric step (one Adam step of the "
                                         "opacities instead of two)")
    soft_depth_ema_gate: float | None = opt(None, "DTU: soft depth only while EMA(0.9) of the hard loss < this")
    depth_patch_range: tuple[int, int] = opt((5, 17), "patch size drawn uniformly in [lo, hi], anew per term")
    depth_patch_div: int = opt(1, "every depth term's patch sizes (as drawn at the views' resolution times this) divided "
                                  "by this, rounded up, at least 2: a fit on views at 1/S of the training resolution "
                                  "(RunConfig.fit_scale) keeps the full-resolution patches' scene area; 1 = as drawn",
                               check=lambda v: None if v in (1, 2, 4) else f"must be 1, 2 or 4, got {v}")
    depth_margin: float = opt(0.00025, 'margin L2: errors with |diff| <= margin are ignored ("error_tolerance")')
    depth_w_local: float = opt(0.1, "weight of the local (per-patch std) normalised depth term")
    depth_w_global: float = opt(1.0, "weight of the global (whole-image std) normalised depth term")
    depth_smooth_weight: float = opt(0.0, "edge-aware depth smoothness weight, in both depth passes (DNGaussian LLFF: 0.1)")
    depth_smooth_from: int = opt(3001, "first iteration of the smoothness term (DNGaussian: iteration > 3000)")
    depth_confidence: float = opt(0.0, "how much the depth prior's confidence c weights each pixel of the depth "
                                       "terms: w = 1 - a + a c (0 = unweighted, DNGaussian; priors without a "
                                       "confidence are unweighted)",
                                  check=lambda v: None if 0 <= v <= 1 else f"must lie in [0, 1], got {v}")
    depth_metric: float = opt(0.0, "the metric depth term (docs/method.md §10): weight of the relative L1 between "
                                   "the photometric pass's rendered depth and the prior's metric depth, per pixel "
                                   "weighted by the prior's confidence (1 where it has none); 0 = off",
                              check=lambda v: None if v >= 0 and v == v and v != float("inf")
                              else f"must be >= 0 and finite, got {v}")
    cross_warp: float = opt(0.0, "the cross-view photometric term (docs/method.md §12): weight of the L1 between "
                                 "the training image and another training view's image, sampled where the "
                                 "photometric pass's rendered depth reprojects each pixel (gradient to the depth "
                                 "only); 0 = off",
                            check=finite_nonneg)
    cross_warp_from: int = opt(1, "first iteration of the cross_warp term")
    cross_warp_occlusion: float = opt(0.0, "the cross_warp term's occlusion test (docs/method.md §12): a pixel is "
                                           "left out where the partner view's rendered surface is nearer than "
                                           "the reprojected point by more than this relative tolerance, z_j > "
                                           "Z_j (1 + tol) (one forward of the partner per iteration); 0 = no test",
                                      check=finite_nonneg)
    cross_warp_blur: tuple[float, ...] = opt((), "the cross_warp term's blur levels (docs/method.md §12): standard "
                                                 "deviations in pixels; the term is also taken on both training "
                                                 "images blurred by a Gaussian of each, and is the mean over the "
                                                 "sharp level and these (each weighted cross_warp / levels); "
                                                 "() = the sharp level only", check=blur_sigmas)
    shape_pena: float = opt(0.0, "weight of mean(max scale / min scale)")
    scale_pena: float = opt(0.0, "weight of mean(max scale^2)")
    opa_pena: float = opt(0.0, "weight of 1 - mean(o^2 | o>0.2) + mean((1-o)^2 | o<0.2)")
    view_warp_weight: float = opt(0.0, "binocular view-consistency term (Han et al. 2024, docs/binocular.md): the "
                                       "weight of the L1 between the training image and a virtual view shifted "
                                       "along the camera x axis, warped back by the rendered depth (authors: 1); "
                                       "0 = off")
    view_warp_smooth: float = opt(0.05, "weight of the edge-aware disparity smoothness inside the view_warp term")
    view_warp_baseline: float = opt(0.4, "largest |baseline| of the virtual view, world units (drawn uniformly "
                                         "per iteration, random sign; authors: 0.4 in COLMAP units)")
    view_warp_from: int = opt(20_000, "first iteration of the view_warp term (authors: 2/3 of the schedule)")
    view_warp_every: int = opt(1, "the view_warp term at every N-th iteration from view_warp_from on, its weight "
                                  "times N (the same weight per iteration on average; its virtual view is a render "
                                  "and a backward more per iteration that takes it; authors: 1); a logging iteration's "
                                  "loss holds the term, at N times the weight, only where it takes it",
                               check=count_at_least_1)
    view_warp_scale: int = opt(1, "the view_warp term at 1/S of the training resolution (speed): the virtual view "
                                  "rendered at 1/S, the term taken on the training render's depth and the training "
                                  "image averaged over S x S blocks with the focal length divided by S, its depth "
                                  "gradient spread back evenly over each block (docs/binocular.md §4.5); 1 = full "
                                  "resolution (Binocular3DGS)",
                               check=lambda v: None if v in (1, 2) else f"must be 1 or 2, got {v}")
    drop_gamma: float = opt(0.0, "DropGaussian (Park et al. 2025, docs/method.md §9): the largest drop rate, "
                                 "reached at the fit's last iteration; at iteration t of T each Gaussian is left "
                                 "out of the photometric pass's renders with rate gamma t / T and the kept ones' "
                                 "opacities are scaled by 1 / (1 - rate); 0 = off",
                            check=lambda v: None if 0 <= v < 1 else f"must lie in [0, 1), got {v}")
    dark_background: bool = opt(False, "DTU (DNGaussian): training pixels darker than 30/255 whose 49 pixels above "
                                       "are dark too are background: ground truth 0 there, and a pass per iteration "
                                       "penalising mean(alpha^2) over them, stepping the opacities only")


@dataclass(frozen=True)
class DensifyConfig:
    """Densification and pruning during a fit."""

    densify_from: int = opt(500, "densify only at iterations > this")
    densify_until: int = opt(15_000, "... and < this (3DGS/DNGaussian `iteration < densify_until_iter`)")
    densify_interval: int = opt(100, "densify every this many iterations")
    grad_threshold: float = opt(0.0002, "mean NDC-scaled screen gradient norm that triggers clone/split")
    percent_dense: float = opt(0.01, "clone if max scale <= this * extent, else split")
    split_opacity_thresh: float | None = opt(None, "DNGaussian: clone/split only Gaussians with opacity > this")
    split_n: int = opt(2, "samples per split Gaussian (scale divided by 0.8 * split_n)")
    prune_opacity: float = opt(0.005, "prune Gaussians with opacity below this at each densification")
    opacity_reset_interval: int | None = opt(3000, "reset opacities to min(o, 0.01) every this many its (None = off)")
    size_prune_from: int | None = opt(3000, "from this iteration (> opacity reset interval in 3DGS) also prune big "
                                            "ones (None = off)")
    max_screen_size: float | None = opt(20.0, "prune if max screen radius (px) exceeds this (with size_prune_from)")
    max_world_size: float | None = opt(0.1, "prune if max scale exceeds this * extent (with size_prune_from)")
    off_frame_margin: float | None = opt(None, "at each densification also drop the Gaussians whose centre lies "
                                               "in no training view's image widened by this fraction of its size "
                                               "on every side (or behind every training camera): the near-camera "
                                               "floaters that cover a novel view whole (docs/method.md §14); "
                                               "None = off", check=finite_nonneg)
    near_prune_radius: float | None = opt(None, "at each densification also drop the Gaussians whose centre lies "
                                                "within this distance (world units) of a training camera's centre: "
                                                "DNGaussian's near pruning on the training cameras only; None = off",
                                          check=finite_nonneg)
    max_gaussians: int | None = opt(None, "optional cap on the Gaussian count (highest-gradient candidates win)")
    clean_views: bool = opt(False, "drop Gaussians no training view sees, at the first iteration (DNGaussian)")
    prune_unseen: bool = opt(False, "at each densification also drop the Gaussians that no pixel of any training "
                                    "view blends (alpha*T summed over the training views = 0): nothing in the "
                                    "training data constrains them (docs/method.md §11)")
    opacity_decay: float | None = opt(None, "multiply every opacity by this factor after each photometric "
                                            "backward, before its Adam step (Binocular3DGS: 0.995); None = off")
    opacity_decay_from: int = opt(500, "the opacity decay runs at iterations > this (authors: densify_from)")
    dark_white_rules: bool = opt(False, "DTU (DNGaussian): at each densification, Gaussians whose DC colour max < "
                                        "20/255 get their gradient accumulator / 10 and opacity 0.1, those with min > "
                                        "240/255 their accumulator / 2")


@dataclass(frozen=True)
class TrainConfig:
    """The recipe of one fit (`reings.train.fit`)."""

    iterations: int = opt(30_000, "training iterations")
    seed: int = opt(0, "seed of every random draw of the fit (view order, patch sizes, split samples)")
    sh_degree: int = opt(3, "maximum SH degree")
    sh_degree_interval: int = opt(1000, "raise the active SH degree by 1 every this many iterations")
    background: tuple[float, float, float] = opt((0.0, 0.0, 0.0), "background colour")
    near: float = opt(0.01, "near plane of the renders")
    optim: OptimConfig = opt(factory=OptimConfig, help="optimizer and learning rates")
    loss: LossConfig = opt(factory=LossConfig, help="losses and weights")
    densify: DensifyConfig = opt(factory=DensifyConfig, help="densification and pruning")

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
                        depth_margin=0.00025, depth_smooth_weight=0.1, depth_smooth_from=3001, view_warp_from=4000,
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
    "3dgs": "original 3DGS: 30k its, (1-0.2)L1 + 0.2 D-SSIM, opacity reset",
    "dngaussian": "DNGaussian LLFF: 6k its, hard+soft depth, SH colour",
    "dngaussian_dtu": "DNGaussian DTU",
}


def preset(name: str) -> TrainConfig:
    """The TrainConfig of a named recipe (ValueError lists the names)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
    return PRESETS[name]
# }}}


# {{{ methods, stages, run presets

METHODS = ("reings", "dngaussian", "3dgs")
ABLATIONS = ("ehps", "ivps", "cvps")  # ReInGSConfig switches, in stage order
ABLATION_METHODS = ("reings-no-ehps", "reings-no-ivps", "reings-no-cvps")
# the stages of each method, in order (reings.pipeline.STAGES holds their functions); the fitting
# ones take RunConfig.iterations in this order
STAGES = {"reings": ("ehps", "coarse", "ivps", "fine", "cvps", "final", "final_prune"),
          "dngaussian": ("init", "dngaussian"),
          "3dgs": ("init", "3dgs")}
# RunConfig.ensemble_from: 'init' is the start of every method; the others are stages (not final_prune,
# which draws nothing: members that share the final fit would be one model)
ENSEMBLE_FROM = ("init", "ehps", "coarse", "ivps", "fine", "cvps", "final", "dngaussian", "3dgs")
FIT_STAGES = {"reings": ("coarse", "fine", "final"), "dngaussian": ("dngaussian",), "3dgs": ("3dgs",)}
RECIPES = ("auto", "llff", "dtu")  # RunConfig.recipe: the recipe family of the fits
DATASETS = ("llff", "llff_nex", "colmap", "dtu", "blender", "nerfstudio", "procedural")


@dataclass(frozen=True)
class RunPreset:
    help: str
    iterations: dict  # method -> iterations per fitting stage (FIT_STAGES order)
    sh_degree: dict  # method -> maximum SH degree
    stereo_seeds: float | None = None  # ReInGSConfig.stereo_seeds where the run leaves it none (None: the auto rule)
    # the recipe families whose reings fits share the soft depth render where the run leaves
    # RunConfig.soft_depth_shared none (docs/results.md §27 for paper's LLFF family)
    soft_depth_shared: tuple = ()


RUN_PRESETS = {
    "quick": RunPreset("3dgs/dngaussian 600 iterations, reings 200/200/600, SH degree 0",
                       {"3dgs": (600,), "dngaussian": (600,), "reings": (200, 200, 600)},
                       {"3dgs": 0, "dngaussian": 0, "reings": 0}),
    # the CPU preset: SH 0, EHPS seeded from the stereo prior at every view count (docs/results.md §18:
    # +3.7 dB at 2 views under a short schedule), the soft depth term on the photometric render (§23), and since
    # session 40 (§51) 600/600/2400 iterations: with today's defaults 300/300/1200 (session 13's) fell 0.36 / 0.44 /
    # 0.21 dB under the full schedule on fern / flower / room (H200, 3 views, seeds 0-2) while taking ~3 of its
    # 10 minutes on 2 Xeon cores; 600/600/2400 is +0.29 / -0.17 / +0.06 dB from the full schedule there
    "fast": RunPreset("the CPU preset: reings 600/600/2400 iterations with the soft depth term on the photometric "
                      "render (--soft-depth-shared), SH 0, EHPS seeded from the stereo prior at every view count "
                      "(--stereo-seeds 0.1); the baselines as quick",
                      {"3dgs": (600,), "dngaussian": (600,), "reings": (600, 600, 2400)},
                      {"3dgs": 0, "dngaussian": 0, "reings": 0}, stereo_seeds=0.1,
                      soft_depth_shared=("llff", "dtu")),
    # SH 1 for reings from the model-size study (docs/results.md): -61% parameters per Gaussian,
    # test PSNR -0.14..+0.37 dB (mean +0.07) against SH 3; the baselines keep their recipes' 3
    # the soft depth term on the photometric render for the 'llff' family since session 17 (H100, full schedule,
    # seeds 0-2: fern + flower 3 views with the stereo prior +0.03 dB, 2 views without a prior 0.00, the held-out
    # NeX trex + room 0.00; fern 3 views 58.2 -> 55.3 s of training with the shared depth order alone, 53.4 with
    # both; docs/results.md §27); 'dtu' since session 18 (scan24 3 views, seeds 0-2: 18.54 -> 18.59 dB, SSIM
    # 0.728 -> 0.733, LPIPS 0.272 -> 0.267; docs/results.md §28)
    "paper": RunPreset("6000 iterations per stage (the paper's schedule); SH degree 1 for reings, 3 for the "
                       "baselines; reings fits take the soft depth term on the photometric render "
                       "(--soft-depth-shared)",
                       {"3dgs": (6000,), "dngaussian": (6000,), "reings": (6000, 6000, 6000)},
                       {"3dgs": 3, "dngaussian": 3, "reings": 1}, soft_depth_shared=("llff", "dtu")),
}


def parse_method(name: str, reings_config: ReInGSConfig | None = None) -> tuple[str, ReInGSConfig]:
    """("reings" | "dngaussian" | "3dgs", ReInGSConfig) of a method name.

    Ablations are spelled as the base name plus switched-off stages: "reings-no-ehps",
    "reings-no-ivps-no-cvps" (paper Table 4). They apply on top of `reings_config`."""
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"unknown method {name!r}: use {', '.join(METHODS)} (ablations: {', '.join(ABLATION_METHODS)})")
    rc = reings_config or ReInGSConfig()
    n = name.strip().lower()
    if n in METHODS:
        return n, rc
    if n.startswith("reings-"):
        parts = n[len("reings-"):].split("-")
        if len(parts) % 2 == 0 and all(a == "no" and b in ABLATIONS for a, b in zip(parts[::2], parts[1::2])):
            off = parts[1::2]
            if len(set(off)) == len(off):
                return "reings", replace(rc, **{k: False for k in off})
    raise ValueError(f"unknown method {name!r}: use {', '.join(METHODS)} or an ablation such as "
                     f"{', '.join(ABLATION_METHODS)} (combine: reings-no-ivps-no-cvps)")


def method_label(base: str, rc: ReInGSConfig) -> str:
    """The inverse of `parse_method`: "reings-no-ehps" etc. (the base name for the baselines)."""
    if base != "reings":
        return base
    return "reings" + "".join(f"-no-{k}" for k in ABLATIONS if not getattr(rc, k))
# }}}


# {{{ checking and converting field values

_HINTS: dict = {}


def _hints(cls) -> dict:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def optional_of(tp):
    """X for `X | None`, else None."""
    args = typing.get_args(tp)
    if type(None) in args and len(args) == 2:
        return next(a for a in args if a is not type(None))
    return None


def type_name(tp) -> str:
    inner = optional_of(tp)
    if inner is not None:
        return type_name(inner) + " or none"
    if typing.get_origin(tp) is tuple:
        return "a list of " + {int: "integers", float: "numbers", str: "strings"}.get(typing.get_args(tp)[0], "values")
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, getattr(tp, "__name__", str(tp)))


def convert(tp, v):
    """`v` as a value of annotation `tp` (numpy scalars -> Python, int -> float, a sequence or a
    single value -> tuple); ValueError with the expected kind if it is none."""
    inner = optional_of(tp)
    if inner is not None:
        return None if v is None else convert(inner, v)
    if is_dataclass(tp):
        if isinstance(v, tp):
            return v
        if isinstance(v, dict):
            return from_dict(tp, v)
    elif typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        seq = list(v) if isinstance(v, (list, tuple)) else [v]
        kinds = [args[0]] * len(seq) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(kinds) == len(seq):
            return tuple(convert(k, x) for k, x in zip(kinds, seq))
    elif tp is bool:
        if isinstance(v, bool) or type(v).__name__ == "bool_":
            return bool(v)
    elif tp is int:
        if isinstance(v, numbers.Integral) and not isinstance(v, bool) and type(v).__name__ != "bool_":
            return int(v)
    elif tp is float:
        if isinstance(v, numbers.Real) and not isinstance(v, bool) and type(v).__name__ != "bool_":
            return float(v)
    elif tp is str:
        if isinstance(v, (str, os.PathLike)):
            return os.fspath(v)
    raise ValueError(f"must be {type_name(tp)}, got {v!r}")


def check_value(f, v):
    """None, or why field `f` refuses value `v` (already converted)."""
    if v is None:
        return None
    md = f.metadata
    if md.get("choices") and v not in md["choices"]:
        return f"must be one of {', '.join(map(str, md['choices']))}, got {v!r}"
    return md["check"](v) if md.get("check") else None


def _coerce_fields(obj) -> None:
    """Convert and check every field of a frozen dataclass in place; ValueError names the field."""
    hints = _hints(type(obj))
    for f in fields(obj):
        try:
            v = convert(hints[f.name], getattr(obj, f.name))
        except ValueError as e:
            raise ValueError(f"{f.name} {e}") from None
        why = check_value(f, v)
        if why:
            raise ValueError(f"{f.name} {why}")
        object.__setattr__(obj, f.name, v)


def from_dict(cls, d: dict, where: str = ""):
    """An instance of dataclass `cls` from a (nested) dict; unknown keys are errors."""
    known = {f.name: f for f in fields(cls)}
    bad = [k for k in d if k not in known]
    if bad:
        raise ValueError(f"unknown key {where + bad[0]!r} (known in {cls.__name__}: {', '.join(known)})")
    hints = _hints(cls)
    kw = {}
    for k, v in d.items():
        tp = hints[k]
        kw[k] = from_dict(tp, v, f"{where}{k}.") if is_dataclass(tp) and isinstance(v, dict) else v
    return cls(**kw)
# }}}


# {{{ RunConfig

@dataclass(frozen=True)
class ReInGSConfig:
    """ReInGS re-initialisation (paper §3): EHPS, IVPS, CVPS, and the final prune."""

    gamma: float = opt(1.4, "EHPS: expansion of the SfM box about its centre", cli="--ehps-gamma",
                       check=lambda v: None if 0 < v < math.inf else f"must be > 0 and finite, got {v}")
    beta1: float = opt(200.0, "EHPS: uniform grid points = beta1 * max side of the expanded box", cli="--ehps-beta1",
                       check=finite_nonneg)
    beta2: float = opt(50.0, "EHPS: uniform random points = beta2 * max side of the expanded box", cli="--ehps-beta2",
                       check=finite_nonneg)
    min_init_points: int = opt(2000, "EHPS: floor on the number of points (scenes in small units; keeps the 4:1 "
                                     "grid:random ratio)", cli="--ehps-min-points", check=at_least(1))
    stereo_seeds: float | None = opt(None, "EHPS, not in the paper: also seed points where the stereo prior is "
                                           "confident: up to this fraction of each training view's pixels (confidence "
                                           ">= stereo_seed_conf, drawn with p ~ confidence), back-projected with the "
                                           "prior's depth and coloured with the pixel; 0 = off; none: 0.1 at 2 training "
                                           "views or when the scene box comes from the stereo prior (SfM found too few "
                                           "points), else off",
                                     check=lambda v: None if v is None or 0 <= v <= 1 else f"must lie in [0, 1], got {v}",
                                     metavar="FRACTION")
    stereo_seed_conf: float = opt(0.5, "EHPS: the least stereo confidence of a seeded pixel (and of a point of the "
                                       "stereo box)",
                                  check=lambda v: None if 0 <= v <= 1 else f"must lie in [0, 1], got {v}")
    delta: float = opt(0.03, "IVPS: weight of the depth-consistency score Omega_D in Omega_P (Eq. 6)",
                       cli="--ivps-delta", check=lambda v: None if 0 <= v <= 1 else f"must be in [0, 1], got {v}")
    ivps_fraction: float = opt(0.10, "IVPS: fraction of the pixels of each training view drawn as new points",
                               check=fraction_open_closed)
    ivps_hard_opacity: float = opt(0.99, "IVPS and the coarse stage's hard depth: the forced opacity of the depth "
                                         "render (Eq. 5)", check=fraction_open_closed)
    ivps_min_alpha: float = opt(0.5, "IVPS: pixels whose hard-render alpha is below this are never drawn",
                                check=lambda v: None if 0 <= v <= 1 else f"must be in [0, 1], got {v}")
    # "expected" by default: the hard depth lands ~70% in front of the surface on the procedural scene
    # (faint EHPS Gaussians own it), the expected depth 15-25% (tests/test_reings_stages.py); quick
    # preset, procedural scene, test PSNR seeds 0/1: hard 14.90/14.87, expected 21.54/20.69
    ivps_depth: str = opt("expected", "IVPS: the depth D that scores and back-projects the pixels: 'expected' "
                                      "(the normal render's depth / alpha, real opacities) or 'hard' (paper Eq. 5 "
                                      "literally: every opacity forced to ivps_hard_opacity)",
                          choices=("expected", "hard"))
    # 0.2 from the model-size study (docs/results.md; H200, full schedule, fern and flower at 2/3/4
    # views): final Gaussians -12..-28%, test PSNR -0.08..+0.55 dB (mean +0.14) against the paper's 0.4
    cvps_fraction: float = opt(0.20, "CVPS: fraction of the fine-stage Gaussians kept, drawn with p ~ Omega_G "
                                     "(Eq. 7-8; the paper's value is 0.4)", check=fraction_open_closed)
    # 0.1 from the same study's prune curves (30 runs): keeping 90% changed test PSNR by -0.02 dB on
    # average (worst -0.22, within the run-to-run spread); 80% cost 0.05 dB, 50% about 1 dB
    final_prune: float = opt(0.1, "reings only, not in the paper: after the final stage remove this fraction of "
                                  "the Gaussians with the lowest Omega_G (Eq. 7, training views only) before "
                                  "evaluation; 0 = off", check=prune_fraction, metavar="FRACTION")
    ehps: bool = opt(True, "EHPS initialisation (off: random points in the SfM box, as DNGaussian; ablation)")
    ivps: bool = opt(True, "IVPS re-initialisation (off: the fine stage starts from the coarse Gaussians; ablation)")
    cvps: bool = opt(True, "CVPS re-initialisation (off: the final stage starts from the fine Gaussians; ablation)")

    def __post_init__(self):
        _coerce_fields(self)


@dataclass(frozen=True)
class OutputConfig:
    """What the run writes and reports."""

    out: str | None = opt(None, "output folder (metrics.json, config.toml, renders, ...); a rerun into it resumes "
                                "an interrupted run. Python only: None = write nothing", metavar="DIR",
                          check=lambda v: None if v is None or v.strip() else "must name a folder, got an empty string")
    lpips: bool = opt(True, "compute LPIPS (and AVGE) on the test views")
    eval_every: int | None = opt(None, "test-PSNR probe every N iterations for the PSNR-vs-seconds plot "
                                       "(none: about 15 per stage; 0: off)", check=at_least(0), metavar="N")
    checkpoint_every: int = opt(250, "rewrite the running stage's checkpoint at every N-th iteration that is at "
                                     "least --checkpoint-seconds after its last one (the stage's end always)",
                                check=at_least(1), metavar="N")
    # issue 15: a checkpoint is a download of the state and a write of ~16 MB at 57k Gaussians (25 ms on
    # 2 PoCL cores), and a paper run wrote 72. 60 s: an H100 paper run (stages of 30-45 s) writes the 3
    # stage ends only; a 40-minute CPU run (250 iterations ~33 s) every 500 iterations. A kill loses at
    # most about the floor plus one checkpoint_every interval (~60 + 33 s there)
    checkpoint_seconds: float = opt(60.0, "write the checkpoint at a multiple of checkpoint_every only when at least S "
                                          "seconds have passed since the stage's last one (or since the fit's start "
                                          "or resume); the end of a stage is always checkpointed; a kill loses at "
                                          "most about S plus one checkpoint_every interval; 0: at every multiple",
                                    check=finite_nonneg, metavar="S")
    profile: bool = opt(False, "record the wall seconds of every training phase (photometric, depth and background "
                               "passes, the view_warp term's renders and kernels, Adam, densification, test-PSNR "
                               "probes, checkpoints) per stage in "
                               "metrics.json `stages[].phases`; the device is waited for around each phase, so the run "
                               "is slower")
    prune_curve: bool = opt(False, "study/reporting: also evaluate test PSNR/SSIM of the final model cut to its top "
                                   "100%, 90%, ..., 40% by training-view Omega_G (metrics.json prune_curve); the "
                                   "test views rank nothing and the reported model is unchanged")

    def __post_init__(self):
        _coerce_fields(self)


@dataclass(frozen=True)
class RunConfig:
    """One `reings run`: a scene, a method, a few-shot split, and how to fit and report it."""

    method: str = opt("reings", "reings | dngaussian | 3dgs, or an ablation: reings-no-ehps, reings-no-ivps, "
                                "reings-no-cvps (combinable: reings-no-ivps-no-cvps); stored as the base name "
                                "with the reings switches set")
    data: str | None = opt(None, "scene folder; none: the built-in procedural scene", metavar="DIR")
    dataset: str | None = opt(None, "scene format (none: detected from the folder)", choices=DATASETS)
    factor: int = opt(8, "image downsampling factor (LLFF: images_8, 504x378)", check=at_least(1))
    views: int = opt(3, "number of training views (>= 2); with --holdout none every view given is used")
    holdout: str = opt("protocol", "which views are held out: 'protocol' (the dataset's published few-shot split; "
                                   "the metrics are on its test views) or 'none' (train on every view given, "
                                   "for your own photos; the metrics are then on the training views)",
                       choices=("protocol", "none"))
    seed: int = opt(0, "seed of every random draw: initial points, IVPS/CVPS draws, and each fit's view order "
                       "and depth patches", check=at_least(0))
    device: str = opt("pocl", "pocl | cuda | cuda:N | opencl:P:D | reference (`reings devices` lists them)")
    preset: str = opt("quick", "schedule: " + "; ".join(f"{k}: {p.help}" for k, p in RUN_PRESETS.items()),
                      choices=tuple(RUN_PRESETS))
    iterations: tuple[int, ...] | None = opt(
        None, "iterations of the fitting stages: N for every stage, or A,B,C for reings' coarse, fine, final "
              "(the baselines take the last); none: the preset's", parse=parse_iterations, check=positive_all,
        metavar="N|A,B,C")
    depth_prior: str = opt("stereo", "stereo | stereo:k=v,... (its options, e.g. stereo:sgm_p1=0.2,sgm_p2=9.6,"
                               "use_bounds=True) | onnx:PATH | none | exact (the procedural scene's true depths)")
    extent: str = opt("sfm", "scene box for EHPS and the random inits: 'sfm' (SfM of the training views; when too "
                             "few points triangulate, the stereo prior's confident pixels, else the training frusta), "
                             "'stereo' (the stereo prior's confident pixels, even where SfM works) or 'frusta' (the "
                             "training frusta directly)", choices=("sfm", "stereo", "frusta"))
    init_points: int = opt(5000, "random initial points of dngaussian/3dgs and of reings without EHPS",
                           check=at_least(1))
    sh_degree: int | None = opt(None, "maximum SH degree; none: the preset's", choices=(0, 1, 2, 3))
    max_gaussians: int | None = opt(None, "cap on the Gaussian count that densification respects in every stage "
                                          "(none: no cap)", check=at_least(1), metavar="N")
    # None: the recipe's 0.1 except with the stereo prior, whose hole-filled edges are not the mono
    # network's the term was designed for; there 30 paired full-schedule runs moved test PSNR by
    # +0.01 dB on average when it was off (docs/results.md)
    depth_smooth: float | None = opt(None, "weight of DNGaussian's edge-aware depth smoothness in every depth pass; "
                                           "none: the recipe's 0.1 (from the middle of each stage), but 0 with the "
                                           "stereo prior; 0 = off", check=finite_nonneg, metavar="WEIGHT")
    recipe: str = opt("auto", "training recipe family of every fit: 'llff' (DNGaussian's LLFF recipe) or 'dtu' "
                              "(DNGaussian's DTU recipe: SSIM weight 0.6, 10x lower means lr, patches 17-53, "
                              "margin 0.01, stronger penalties, soft depth gated by the hard loss, no "
                              "smoothness); auto: 'dtu' for DTU scenes, else 'llff'", choices=RECIPES)
    # on by default from the H100 ablation of docs/results.md §9 (LLFF fern+flower, 3 views, seeds 0-2, full
    # schedule): +0.54 dB on fern, +0.84 on flower, SSIM +0.022 alone; the opacity decay stays off: it moved
    # flower by -1.58 dB alone and -0.26 dB on top of the term (fern: +0.46 / +0.47)
    view_warp: float = opt(1.0, "reings fits only: weight of the binocular view-consistency term (Han et al. "
                                "2024; docs/binocular.md) from 2/3 of each fit (1/3 for 'llff' with --depth-prior "
                                "none; --view-warp-start); 0 = off", check=finite_nonneg, metavar="WEIGHT")
    view_warp_start: float | None = opt(None, "reings fits only: where the view_warp term starts, as a fraction of "
                                              "each fit's iterations; none: the recipe family's (1/3 for 'llff' "
                                              "with --depth-prior none, else 2/3 as Binocular3DGS; docs/results.md "
                                              "§25)",
                                        check=lambda v: None if v is None or 0 <= v < 1
                                        else f"must lie in [0, 1), got {v}", metavar="FRACTION")
    view_warp_disparity: float = opt(4.0, "the view_warp term's largest virtual-view shift, in pixels at the median "
                                          "depth of the scene's SfM points in the training views (scale-free; the "
                                          "authors' 0.4 COLMAP units is 2.6-5.5 px on the LLFF scenes here)",
                                     check=lambda v: None if v > 0 and v == v and v != float("inf")
                                     else f"must be positive and finite, got {v}", metavar="PIXELS")
    view_warp_every: int = opt(1, "reings fits only: the view_warp term at every N-th iteration from its start, its "
                                  "weight times N (its virtual view is a render and a backward more in each iteration "
                                  "that takes it: speed, issue 15); 1 = every iteration (Binocular3DGS; at 2, full "
                                  "schedule, 3 views, seeds 0-2: fern -0.06, flower -1.42 (seeds 0 and 2 fell 1.8 and "
                                  "2.7 dB), room +0.19 dB; fern's training -3 percent on an H200; docs/results.md §51)",
                               check=count_at_least_1, metavar="N")
    view_warp_scale: int = opt(1, "reings fits only: the view_warp term at 1/S of the training resolution (its virtual "
                                  "view rendered at 1/S, the term on the training render's depth and image averaged "
                                  "over S x S blocks, docs/binocular.md §4.5; in a fit at --fit-scale F, at 1/max(1, "
                                  "S // F) of that fit's views: speed, issue 15); 1 = full resolution (Binocular3DGS)",
                               check=lambda v: None if v in (1, 2) else f"must be 1 or 2, got {v}", metavar="S")
    # none -> the recipe family's: on for DTU (scan24 3 views, seeds 0-2: 16.06 dB with it, 14.90 without),
    # off for LLFF (fern+flower 2 views: 18.36 with it, 19.07 without; 3 views: 21.06 / 20.96, flower
    # -0.26 dB): docs/results.md §9
    opacity_decay: float | None = opt(None, "reings fits only: multiply every opacity by this factor each iteration "
                                            "after densification starts (Binocular3DGS: 0.995); 1 = off; none: the "
                                            "recipe family's (0.995 for 'dtu', off for 'llff')",
                                      check=lambda v: None if v is None or 0 < v <= 1 else f"must lie in (0, 1], got {v}",
                                      metavar="FACTOR")
    depth_confidence: float = opt(0.0, "every fit with depth terms: how much the stereo prior's confidence c "
                                       "weights each pixel of the depth loss, w = 1 - a + a c (0 = unweighted, "
                                       "DNGaussian; 1 = the confidence alone)",
                                  check=lambda v: None if 0 <= v <= 1 else f"must lie in [0, 1], got {v}",
                                  metavar="A")
    hard_depth_scale: int | None = opt(None, "every fit with the hard depth term: render its pass at 1/S of the "
                                             "training resolution, against the depth prior averaged over S x S "
                                             "blocks (speed, issue 15; docs/perf_notes.md §23, §34); 1 = full "
                                             "resolution (DNGaussian; in a fit at --fit-scale F > 1 the pass runs at "
                                             "the fit's own 1/F at least: --fit-scale 1 for the full pass); none: the recipe family's for the reings fits "
                                             "(2 for 'llff': with --hard-depth-patches area, fern / flower / room / "
                                             "trex at 3 views, seeds 0-2, -0.06 / +0.15 / +0.29 / +0.01 dB against 1, "
                                             "docs/results.md §49; 1 for 'dtu', not measured) and 1 for the baselines",
                                       check=lambda v: None if v in (None, 1, 2, 4) else f"must be 1, 2 or 4, got {v}",
                                       metavar="S")
    hard_depth_patches: str = opt("area", "at a hard depth scale S > 1: the hard depth loss's patch sizes divided "
                                          "by S, rounded up ('area': the full-resolution patches' scene area), or as "
                                          "drawn in the small pass's pixels ('pixels': scale^2 times the area, the "
                                          "option's meaning until session 38: -0.11 / -0.17 / +0.37 dB)",
                                  choices=("pixels", "area"))
    lambda_dssim: tuple[float, ...] | None = opt(
        None, "the SSIM weight l of the photometric loss L1 + l (1 - SSIM) (the 3dgs baseline's: (1 - l) L1 + "
              "l (1 - SSIM), l <= 1): L for every fit, or A,B,C for reings' coarse, fine, final (the baselines "
              "take the last); none: the recipe's (DNGaussian: 0.2 for 'llff', 0.6 for 'dtu'; 3DGS: 0.2), "
              "except reings fits of the 'llff' family with --depth-prior none: 0.2,0.4,0.4 (docs/results.md "
              "§28)",
        parse=parse_lambda_dssim, check=lambda_dssim_values, metavar="L|A,B,C")
    fit_scale: tuple[int, ...] | None = opt(
        None, "reings fits: fit the training views at 1/S of their resolution (the images averaged over S x S "
              "blocks, the intrinsics divided by S, the depth prior and its confidence averaged as the images; the "
              "hard depth pass at its own scale divided by S, at least 1; every depth patch keeps its "
              "full-resolution scene area; speed, issue 15): S for every reings fit, or A,B,C for coarse, fine, "
              "final; the re-initialisations (IVPS, CVPS), probes and the evaluation render at full resolution; "
              "the settings in pixels (the DTU dark-background mask, cross_warp's blur sigmas) are then taken in "
              "the fit's own pixels; a hard pass at the fit's own resolution keeps the full-resolution patch area "
              "whatever --hard-depth-patches says, one coarser than the fit takes 'pixels' patches in the fit's own "
              "pixels; "
              "none: the recipe family's (2,1,1 for 'llff': fern / flower / room / trex at 3 views, seeds 0-2, "
              "+0.00 / +0.03 / +0.25 / -0.12 dB against 1, docs/results.md §52; 1 for 'dtu' and for runs without a "
              "depth prior, not measured); the baselines fit at 1",
        parse=parse_fit_scale, check=lambda v: None if v is None else fit_scale_values(v), metavar="S|A,B,C")
    max_screen_fraction: float | None = opt(
        None, "reings fits: at each densification step also prune the Gaussians whose largest screen radius (3 "
              "sigma) in a training view since the last step exceeds F times the largest image side of the fit's "
              "views (a variant of 3DGS's screen-size prune: relative to the image, and from the densification's "
              "start where 3DGS waits for its first opacity reset; against the near-camera floaters that cover a "
              "novel view whole); none / 0: off (DNGaussian's recipes have no size prune; at 1 it cured two "
              "collapsed flower runs but cost the default flower 0.17 dB (seeds 0-2) and room 0.43 dB (seed 0), "
              "docs/method.md §14)",
        check=finite_nonneg, metavar="F")
    off_frame_margin: float | None = opt(
        None, "reings fits: at each densification step also drop the Gaussians whose centre lies in no training "
              "view's image widened by F times its size on every side (DensifyConfig.off_frame_margin; the "
              "near-camera floaters beside the training cameras that cover a novel view whole, docs/method.md "
              "§14); none: off",
        check=finite_nonneg, metavar="F")
    near_prune: float | None = opt(
        None, "reings fits: at each densification step also drop the Gaussians whose centre lies within F times "
              "the scene's near depth of a training camera's centre (DensifyConfig.near_prune_radius; the near depth: "
              "the smallest over the training views of the 1st percentile of the depths of the scene box's points: the "
              "SfM of the training views, or the stereo prior's where the box is the prior's; DNGaussian's LLFF near pruning, which reads the render path's poses, on the training "
              "cameras only: against the near-camera floaters that cover a novel view whole, docs/method.md §14); "
              "none: off; a run whose box has no points ignores it (with a note)",
        check=finite_nonneg, metavar="F")
    fit_scale_share: tuple[float, ...] | None = opt(
        None, "reings fits at a --fit-scale S > 1: the share of the fit's iterations run at 1/S, its first ones "
              "(rounded, at least 1); the rest at full resolution, the parameters, Adam moments and densification "
              "statistics carried over (a coarse-to-fine schedule inside one fit; speed, issue 15): F for every "
              "reings fit, or A,B,C for coarse, fine, final; none: 1 (the whole fit at 1/S). Measured (H200, 3 "
              "views, seeds 0-2, against the default 2,1,1): --fit-scale 2,2,2 with 1,0.67,0.5 fern / flower / room / "
              "trex -0.16 / -0.14 / +0.24 / -0.19 dB; 2,2,1 with 1,0.5,1 broke flower on 2 of 3 seeds "
              "(docs/results.md §53)",
        parse=parse_fit_scale_share, check=lambda v: None if v is None else fit_scale_share_values(v),
        metavar="F|A,B,C")
    grad_threshold_scale: float = opt(1.0, "every fit: multiplies the recipe's densification threshold on the mean "
                                           "screen-space gradient (DNGaussian: 0.0013 for 'llff', 0.001 for 'dtu'; 3DGS: 0.0002); "
                                           "1 = the recipe's",
                                      check=lambda v: None if v > 0 and v == v and v != float("inf")
                                      else f"must be positive and finite, got {v}", metavar="FACTOR")
    soft_depth_shared: bool | None = opt(None, "every fit with the soft depth term: share the photometric pass's "
                                                "render with it, and step the opacities once with both gradients "
                                                "(speed, issue 15); none: the preset's for the reings fits (fast and "
                                                "paper: on; quick: off) and off "
                                                "for the baselines")
    drop_gamma: float | None = opt(None, "reings and dngaussian fits: DropGaussian (Park et al. 2025; docs/method.md "
                                         "§9): each Gaussian is left out of the photometric pass's renders with a rate "
                                         "rising linearly to this at each fit's last iteration, the kept ones' "
                                         "opacities scaled by 1 / (1 - rate); 0 = off; none: the recipe family's "
                                         "for reings (0.2 for 'dtu' and 'llff', 0.3 for 'llff' with --depth-prior none; "
                                         "docs/results.md §19, §20, §25), off for dngaussian",
                                   check=lambda v: None if v is None or 0 <= v < 1 else f"must lie in [0, 1), got {v}",
                                   metavar="GAMMA")
    depth_metric: float | None = opt(None, "reings fits with a metric depth prior (stereo, exact): the metric depth "
                                           "term's weight (docs/method.md §10): the photometric pass's rendered depth "
                                           "against the prior's metric depth, relative L1 weighted by the prior's "
                                           "confidence; 0 = off; none: the recipe family's (off for 'llff' and 'dtu')",
                                     check=lambda v: None if v is None or (v >= 0 and v == v and v != float("inf"))
                                     else f"must be >= 0 and finite, got {v}", metavar="WEIGHT")
    cross_warp: float | None = opt(None, "reings fits only: weight of the cross-view photometric term (docs/method.md "
                                         "§12): the rendered depth of the view being trained reprojects its pixels "
                                         "into another training view, whose training image must match there (L1, "
                                         "gradient to the depth only; no prior needed); 0 = off; none: the recipe "
                                         "family's (0.15 for 'llff' with --depth-prior none, off for 'dtu' and with "
                                         "any depth prior; docs/results.md §24, §25)", check=finite_nonneg,
                                   metavar="WEIGHT")
    cross_warp_start: float = opt(0.0, "reings fits only: where the cross_warp term starts, as a fraction of each "
                                       "fit's iterations (0: from the first)",
                                  check=lambda v: None if 0 <= v < 1 else f"must lie in [0, 1), got {v}",
                                  metavar="FRACTION")
    cross_warp_occlusion: float = opt(0.0, "reings fits only: the cross_warp term's occlusion test (docs/method.md "
                                           "§12): the partner view's depth is rendered too (one forward per "
                                           "iteration), and a pixel whose reprojected point lies behind the "
                                           "partner's surface, z_j > Z_j (1 + TOL), is left out of the term; "
                                           "0 = no test",
                                      check=finite_nonneg, metavar="TOL")
    cross_warp_blur: tuple[float, ...] = opt((), "reings fits only: the cross_warp term's blur levels "
                                                 "(docs/method.md §12), comma-separated Gaussian standard "
                                                 "deviations in pixels (e.g. 2,4): the term is also taken on both "
                                                 "training images blurred by each (a wider basin for the depth), "
                                                 "and is the mean over the sharp level and these; none: the sharp "
                                                 "level only (measured worse at 2 views without a prior, "
                                                 "docs/results.md §25, so none by default)", parse=parse_blur_sigmas, check=blur_sigmas,
                                             metavar="SIGMAS")
    prune_unseen: bool | None = opt(None, "reings fits: at each densification also drop the Gaussians that no "
                                          "pixel of any training view blends (docs/method.md §11); none: the "
                                          "recipe family's (on for 'llff', off for 'dtu' until measured there; "
                                          "docs/results.md §20)")
    dtu_background: bool = opt(False, "every fit: DNGaussian's DTU background rules (dark-pixel mask of the training "
                                      "views, ground truth 0 there, the mean(alpha^2) pass, the black / white Gaussian "
                                      "rules; reings/background.py); not yet measured, so off")
    ensemble: int | None = opt(None, "fit K models (members) and render their mean image: member k is the whole "
                                     "method with seed + k * 1000003 (member 0 is the plain run), the stages "
                                     "before --ensemble-from shared; the test metrics are the mean image's, each "
                                     "member's own PSNR and SSIM are in metrics.json, the models are gaussians.ply and "
                                     "gaussians_member<k>.ply (docs/method.md §13); 1 = one model; none: the "
                                     "recipe family's for reings (2 for 'dtu', 1 for 'llff'; docs/results.md §36), 1 for the "
                                     "baselines",
                               check=at_least(1), metavar="K")
    ensemble_from: str = opt("init", "with --ensemble K > 1: the first stage the members do not share: 'init' (none "
                                     "shared: independent fits) or a stage of the method (reings: ehps, coarse, "
                                     "ivps, fine, cvps, final; 'cvps' shares the coarse and fine fits)",
                             choices=ENSEMBLE_FROM, metavar="STAGE")
    ensemble_jobs: int = opt(1, "with --ensemble K > 1: how many members fit at once, member 0 in this process and "
                                "each other one in a worker process of its own on the same device (the same "
                                "results; on one H100 two at once took 5-11 % less wall time, as the members "
                                "share the GPU, and seconds.method then sums overlapping clocks: docs/results.md "
                                "§36)", check=at_least(1), metavar="J")
    reings: ReInGSConfig = opt(factory=ReInGSConfig, help="the ReInGS stages")
    output: OutputConfig = opt(factory=OutputConfig, help="outputs and reports")

    def __post_init__(self):
        _coerce_fields(self)
        base, rc = parse_method(self.method, self.reings)
        object.__setattr__(self, "method", base)
        object.__setattr__(self, "reings", rc)
        if self.dataset == "procedural" and self.data not in (None, "procedural"):
            raise ValueError(f"dataset procedural is the built-in scene and takes no data folder, got data {self.data!r}")
        if self.views < 2:
            raise ValueError(f"views must be an integer >= 2 (the SfM box needs two training views), got {self.views}")
        from .data.depth_prior import prior_kind

        if self.depth_metric and self.method == "reings" and prior_kind(self.depth_prior) not in METRIC_PRIORS:
            raise ValueError(f"depth_metric compares the rendered depth with a metric depth prior "
                             f"({', '.join(METRIC_PRIORS)}), but depth_prior is {self.depth_prior!r}: use "
                             f"--depth-prior stereo or --depth-metric 0")
        if self.method == "3dgs" and self.lambda_dssim is not None and self.lambda_dssim[-1] > 1:
            raise ValueError(f"lambda_dssim: the 3dgs baseline's loss is (1 - l) L1 + l (1 - SSIM), so l must lie in "
                             f"[0, 1] (above 1 the L1 weight is negative), got {self.lambda_dssim[-1]}")
        if self.extent == "stereo" and prior_kind(self.depth_prior) != "stereo":
            raise ValueError(f"extent stereo takes the scene box from the stereo depth prior, but depth_prior is "
                             f"{self.depth_prior!r}: use --depth-prior stereo or another --extent")
        if self.ensemble_from != "init" and self.ensemble_from not in STAGES[self.method]:
            raise ValueError(f"ensemble_from: {self.ensemble_from!r} is not a stage of {self.method} (its stages: init, "
                             f"{', '.join(s for s in STAGES[self.method] if s in ENSEMBLE_FROM and s != 'init')})")
        if self.iterations is not None and len(self.iterations) not in (1, 3):
            raise ValueError(f"iterations must be one count or three (reings: coarse, fine, final), "
                             f"got {self.iterations}")

    @property
    def label(self) -> str:
        """The method's name with its ablations: "reings-no-ivps", "dngaussian"."""
        return method_label(self.method, self.reings)

    def resolved(self) -> RunConfig:
        """This config with the preset's values filled in: `iterations` one count per fitting stage
        (FIT_STAGES), `sh_degree` an integer."""
        p = RUN_PRESETS[self.preset]
        n = len(FIT_STAGES[self.method])
        its = self.iterations or p.iterations[self.method]
        its = its * n if len(its) == 1 else its[-n:]
        sh = p.sh_degree[self.method] if self.sh_degree is None else self.sh_degree
        return replace(self, iterations=its, sh_degree=sh)

    def stage_lambda_dssim(self, stage: str | None) -> float | None:
        """The SSIM weight of fitting stage `stage`: none (the recipe's), else `stage_value`."""
        return None if self.lambda_dssim is None else stage_value(self.lambda_dssim, stage)

    def stage_iterations(self) -> dict:
        """{fitting stage name: iterations} of the resolved config."""
        r = self.resolved()
        return dict(zip(FIT_STAGES[r.method], r.iterations))


def leaf_fields(cls=RunConfig, prefix: str = ""):
    """(dotted path, field, type) of every non-dataclass field under `cls`, in declaration order."""
    hints = _hints(cls)
    for f in fields(cls):
        tp = hints[f.name]
        if is_dataclass(tp):
            yield from leaf_fields(tp, prefix + f.name + ".")
        else:
            yield prefix + f.name, f, tp


METRIC_PRIORS = ("stereo", "exact")  # the depth priors whose depth is metric (RunConfig.depth_metric)

LEGACY_KEYWORDS = {"reings_config": "reings", "with_lpips": "output.lpips"}


def with_values(cfg, values: dict):
    """A copy of `cfg` with `values` {dotted path or unique leaf name: value} set; KeyError names an
    unknown key. Sections are rebuilt first, so the method's ablations apply to the new switches."""
    paths = {p: p for p, _, _ in leaf_fields(type(cfg))}
    paths.update({p.rsplit(".", 1)[-1]: p for p in list(paths)})  # leaf names are unique in RunConfig
    paths.update({f.name: f.name for f in fields(cfg)})
    paths.update(LEGACY_KEYWORDS)
    nested: dict = {}
    for k, v in values.items():
        if k not in paths:
            raise KeyError(k)
        head, _, rest = paths[k].partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = v
        else:
            nested.setdefault(head, {})[""] = v
    kw = {}
    for head, sub in nested.items():
        cur = sub.pop("", getattr(cfg, head))
        if sub and not is_dataclass(cur):  # e.g. run(output=5, out=...): name the section, not dataclasses
            raise ValueError(f"{head} must be {type_name(_hints(type(cfg))[head])}, got {cur!r}")
        kw[head] = with_values(cur, sub) if sub else cur
    return replace(cfg, **kw)


def run_config(config: RunConfig | None = None, **keywords) -> RunConfig:
    """`config` (default RunConfig()) with `keywords` set: RunConfig's field names, their sections'
    leaf names (`cvps_fraction=0.4`, `eval_every=0`, `out=`), or the older `reings_config=` and
    `with_lpips=`. TypeError names an unknown keyword."""
    cfg = config if config is not None else RunConfig()
    try:
        return with_values(cfg, keywords)
    except KeyError as e:
        raise TypeError(f"run() got an unexpected keyword argument {e.args[0]!r}") from None
# }}}


# {{{ TOML

def to_toml(cfg) -> str:
    """`cfg` (a dataclass) as a TOML document: one key per field with its help as a comment, a
    table per nested dataclass; a None field is written as a comment (absent = None on loading)."""
    from .io.toml import dumps

    return dumps(cfg, title=f"reings {type(cfg).__name__} (load with: reings run --config THIS_FILE)")


def load_run_config(path) -> RunConfig:
    """The RunConfig of a TOML file (`reings run --config`); ValueError names the file and key."""
    from .io.toml import loads

    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise FileNotFoundError(f"--config {path}: {e.strerror or e}") from None
    try:
        return from_dict(RunConfig, loads(data.decode("utf-8")))
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
# }}}
