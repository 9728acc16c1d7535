"""`reings run` / `reings.run`: one scene, end to end, as a list of stages.

    RunConfig -> checks (nothing written yet) -> data -> few-shot split (the training side gets
    ONLY the training views) -> depth prior -> scene box -> the method's stages -> test-view
    evaluation -> outputs (`reings.outputs`)

The stages of each method, in order (`reings.config.STAGES` names them, `STAGE_FUNCTIONS` below
maps the names to functions, `stages_of(method)` pairs them). A stage's name is its key in
metrics.json `gaussians`, `seconds`, `model_bytes` and `stages`, and its log line:

    reings      ehps -> coarse -> ivps -> fine -> cvps -> final -> final_prune   (paper Eq. 4-9)
    dngaussian  init -> dngaussian
    3dgs        init -> 3dgs

    init         random points in the scene box (DNGaussian's initialisation; like ehps, not on
                 the method clock, seconds["method"])
    ehps         EHPS points (`ReInGSConfig.ehps` off: as init)
    coarse       fit: DNGaussian's recipe with the hard depth term only (opacity ivps_hard_opacity)
    ivps         IVPS points from the coarse model (off: the coarse Gaussians go on)
    fine, final  fit: DNGaussian's recipe with the soft depth term only (paper Eq. 9)
    cvps         CVPS: a draw of the fine Gaussians, colour kept (off: the fine Gaussians go on)
    final_prune  remove the lowest `ReInGSConfig.final_prune` fraction by training-view Omega_G
                 (not in the paper; 0 = the stage does nothing and records nothing)
    dngaussian, 3dgs   one fit with the method's recipe

A stage is `f(ctx, name) -> Gaussians`: it reads the current Gaussians `ctx.g` and the shared
`RunContext` (config, views, priors, box, device, random generator, clock, records) and returns
the next ones. The re-initialisation maths is `reings.reinit`; the files `reings.outputs`.
A rerun into the same folder resumes: each fit reloads its checkpoint, and the stages between
fits are recomputed from the same draws (`tests/test_pipeline.py`).

An ensemble (RunConfig.ensemble K > 1, docs/method.md §13) runs the stages from `ensemble_from` on
K times: member 0 is the plain run, member k a `RunContext.member` with seed + k * MEMBER_SEED_STRIDE
and its own checkpoints (checkpoints/member<k>_<stage>.npz), starting from the shared stages'
model. The test views are scored on the mean of the members' images (`score_test_views`).
"""
from __future__ import annotations

import copy
import dataclasses
import os
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .config import FIT_STAGES, RUN_PRESETS, ReInGSConfig, RunConfig, run_config, stage_value  # noqa: F401 (ReInGSConfig: re-exported)
from .data.depth_prior import NO_PRIOR, prior_kind
from .ensemble import fit_members, jobs_of
from .reinit import (cvps_select, ehps_init, gaussian_importance, ivps_points, prune_keep_indices,
                     stereo_box, stereo_seed_points)
from .train import FitLead, builds_since, fit, gaussians_from_points, kernel_builds, random_points_in_box, scene_extent, with_iterations

PRUNE_CURVE_KEEP = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4)


@dataclass
class RunResult:
    gaussians: object  # the model (member 0 of an ensemble)
    metrics: dict
    stages: list = field(default_factory=list)
    members: list = field(default_factory=list)  # every member's model, gaussians first (one for a single model)


# {{{ small helpers

def _depths_per_camera(cameras, pts, stat) -> list:
    """`stat` of the camera-space z of the points `pts` [P, 3] in front of each camera (finite, > 0), for
    the cameras that have any."""
    pts = np.asarray(pts, np.float64).reshape(-1, 3)
    out = []
    for cam in cameras:
        z = pts @ cam.viewmat[2, :3] + cam.viewmat[2, 3]
        z = z[np.isfinite(z) & (z > 0)]
        if len(z):
            out.append(float(stat(z)))
    return out


def typical_depth(cameras, box) -> float:
    """The scene's typical depth from the training views: the median over the cameras of the
    median camera-space z of the SfM points in front of them (box.points), or, without points,
    of the box centre's z (at least 1e-6)."""
    pts = np.asarray(box.points, np.float64).reshape(-1, 3)
    if not len(pts):
        pts = (0.5 * (np.asarray(box.lo, np.float64) + np.asarray(box.hi, np.float64)))[None]
    meds = _depths_per_camera(cameras, pts, np.median)
    return max(float(np.median(meds)) if meds else 1.0, 1e-6)


def near_depth(cameras, box, q: float = 1.0) -> float | None:
    """The scene's near depth from the training views: the smallest over the cameras of the q-th
    percentile of the camera-space z of the scene box's points in front of them (box.points: the SfM
    points of the training views, or the stereo prior's confident points where the box is the prior's);
    None without points (RunConfig.near_prune then has no scale)."""
    near = _depths_per_camera(cameras, box.points, lambda z: np.percentile(z, q))
    return min(near) if near else None


def auto_eval_every(iters: int, points: int = 15) -> int:
    """Test-PSNR probes every this many iterations: about `points` per stage."""
    return max(1, int(round(iters / points)))


def gaussians_nbytes(g) -> int:
    """Bytes of the Gaussian parameters (means, quats, scales, opacities, SH) as held on the host."""
    return int(sum(np.asarray(getattr(g, f)).nbytes for f in ("means", "quats", "log_scales", "opacity_logits", "sh")))


def device_peak_bytes(backend) -> int | None:
    """High-water mark of the backend's device buffers in this process (None if not tracked)."""
    for obj in (backend, getattr(backend, "scratch", None)):
        v = getattr(obj, "peak_bytes", None) if obj is not None else None
        if v is not None:
            return int(v)
    return None


def binning_of(backend) -> dict | None:
    """The backend's binning mode (OpenCL: "auto" / "sync" / "async", docs/perf_notes.md §8) and the
    forwards binned in each mode in this process; None where the backend has none (`reference`)."""
    mode = getattr(backend, "bin_mode", None)
    return None if mode is None else {"mode": mode, **getattr(backend, "binned", {})}


def _peak_rss_mb() -> float | None:
    """This process's peak resident memory in MiB (None where the platform has no `resource`:
    Windows). ru_maxrss is in KiB on Linux, in bytes on macOS."""
    try:
        import resource
    except ImportError:
        return None
    v = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return v / 2**20 if sys.platform == "darwin" else v / 1024


def test_psnr(g, test, device, bg, near) -> float:
    """Mean per-image PSNR of the test views (DTU: masked), no LPIPS: the cheap probe."""
    from .metrics import psnr
    from .rendering import render

    vals = []
    for i, (cam, ref) in enumerate(zip(test.cameras, test.images)):
        r = render(g, cam, device, bg, near)
        m = None if test.masks is None else test.masks[i]
        vals.append(psnr(np.clip(r.rgb, 0, 1), ref, mask=m))
    return float(np.mean(vals))


def render_views(g, cameras, device, bg, near, per_member: list | None = None) -> tuple[list, list]:
    """(renders [H, W, 3] clipped to [0, 1], depths [H, W] = depth / alpha) of `cameras`; `g` a list of
    models (an ensemble's members): the mean of their clipped renders and of their depths, and
    with `per_member` (an empty list) each member's clipped renders appended to it, one list per
    member (rendered once for both)."""
    from .rendering import render

    members = list(g) if isinstance(g, (list, tuple)) else [g]
    if per_member is not None:
        per_member[:] = [[] for _ in members]
    preds, depths = [], []
    for cam in cameras:
        rs = [render(m, cam, device, bg, near) for m in members]
        rgbs = [np.clip(r.rgb, 0, 1) for r in rs]
        for kept, rgb in zip(per_member or (), rgbs):
            kept.append(rgb)
        preds.append(sum(rgbs) / len(rgbs) if len(rgbs) > 1 else rgbs[0])
        ds = [r.depth / np.maximum(r.alpha, 1e-6) for r in rs]
        depths.append(sum(ds) / len(ds) if len(ds) > 1 else ds[0])
    return preds, depths


def score_test_views(g, test, device, bg, near, with_lpips=True, per_member: list | None = None):
    """(metrics of `evaluate_images`, renders [H, W, 3] in [0, 1], depths [H, W] = depth / alpha) of
    the test views; without an LPIPS model, metrics without LPIPS and an `lpips_error`. `g` a list
    of models (an ensemble): the metrics of the mean image, and `per_member` filled with each
    member's renders (`render_views`)."""
    from .metrics import LPIPSModelNotFound, evaluate_images

    preds, depths = render_views(g, test.cameras, device, bg, near, per_member)
    try:
        m = evaluate_images(preds, list(test.images), masks=test.masks, with_lpips=with_lpips)
    except LPIPSModelNotFound as e:  # no LPIPS model on this machine: report without it
        m = evaluate_images(preds, list(test.images), masks=test.masks, with_lpips=False)
        m["lpips_error"] = str(e)
    return m, preds, depths


def prune_curve_points(g, omega, test, device, bg, near, keeps=PRUNE_CURVE_KEEP) -> list:
    """Test PSNR/SSIM (no LPIPS) of `g` restricted to its top `keep` fraction by `omega`, per keep:
    [{"keep", "gaussians", "psnr", "ssim"}]. Reporting only: the test views rank nothing."""
    pts = []
    for keep in keeps:
        gk = g.subset(prune_keep_indices(omega, keep))
        m, _, _ = score_test_views(gk, test, device, bg, near, with_lpips=False)
        pts.append({"keep": float(keep), "gaussians": len(gk), "psnr": m.get("psnr"), "ssim": m.get("ssim")})
    return pts


def load_run_scene(data, dataset=None, factor=8):
    """`load_scene` for a run: LLFF's full-view COLMAP points are not read (the few-shot side
    never uses them, and reading them needs pycolmap, which a GPU machine may lack). The built-in
    procedural scene comes from the on-disk cache when it is there (`make_procedural_scene`)."""
    from .data.loader import canonical_kind, detect_format, load_scene

    if (canonical_kind(dataset) == "procedural") if dataset else (data is None or str(data) == "procedural"):
        return load_scene(data, dataset, factor=factor, disk_cache=True)  # load_scene's rule for the built-in scene
    kind = canonical_kind(dataset) if dataset else detect_format(os.fspath(data))
    kw = {"load_points": False} if kind in ("llff", "llff_nex") else {}
    return load_scene(data, dataset, factor=factor, **kw)


def run_settings(cfg: RunConfig, dataset_kind: str) -> dict:
    """The settings a resume must match (checkpoints/run.json; metrics.json `config`), from a
    resolved RunConfig. Keys absent at their old default keep older run folders resumable."""
    rc = dataclasses.asdict(cfg.reings)
    if not rc.get("final_prune"):  # 0 = the value before the option existed
        rc.pop("final_prune", None)
    if rc.get("stereo_seed_conf") == 0.5:  # the default since the option exists
        rc.pop("stereo_seed_conf")
    auto_seeds = rc.get("stereo_seeds", 0) is None
    if auto_seeds:  # none (auto): absent where the auto rule adds nothing, as before the option existed
        rc.pop("stereo_seeds")
        auto_seeds = cfg.method == "reings" and cfg.reings.ehps  # the only fits it seeds
    s = {"method": cfg.label, "data": None if cfg.data is None else os.path.abspath(cfg.data),
         "dataset": dataset_kind, "views": cfg.views, "preset": cfg.preset, "iterations": list(cfg.iterations),
         "seed": cfg.seed, "depth_prior": cfg.depth_prior, "factor": cfg.factor, "init_points": cfg.init_points,
         "sh_degree": cfg.sh_degree, "reings_config": rc, "max_gaussians": cfg.max_gaussians, "extent": cfg.extent}
    if cfg.depth_smooth is not None:
        s["depth_smooth"] = cfg.depth_smooth
    if cfg.recipe != "auto":  # "auto" is the value before the option existed
        s["recipe"] = cfg.recipe
    if cfg.dtu_background:
        s["dtu_background"] = True
    if cfg.depth_confidence:  # absent at 0, the value before the option existed
        s["depth_confidence"] = cfg.depth_confidence
    family = recipe_family(cfg.recipe, dataset_kind)
    fs = [fit_scale_of(cfg, family, st) for st in FIT_STAGES[cfg.method]]
    if cfg.off_frame_margin is not None and cfg.method == "reings":  # absent when off, as before the option
        s["off_frame_margin"] = cfg.off_frame_margin
    if cfg.near_prune is not None and cfg.method == "reings":  # absent when off, as before the option
        s["near_prune"] = cfg.near_prune
    if cfg.max_screen_fraction and cfg.method == "reings":  # absent when off, the value before the option existed
        s["max_screen_fraction"] = cfg.max_screen_fraction
    if any(v != 1 for v in fs):  # absent at 1, the value before the option existed
        s["fit_scale"] = fs
        share = [fit_scale_share_of(cfg, st) if f != 1 else 1.0 for f, st in zip(fs, FIT_STAGES[cfg.method])]
        if any(v != 1 for v in share):  # absent at 1 (the whole fit at its scale), the value before the option
            s["fit_scale_share"] = share
    hd = hard_depth_scale_of(cfg, family)
    if hd != 1:  # absent at 1, the value before the option existed
        s["hard_depth_scale"] = hd
        if cfg.hard_depth_patches != "pixels":  # absent at pixels, the only meaning before session 38
            s["hard_depth_patches"] = cfg.hard_depth_patches
    lam = [lambda_dssim_of(cfg, family, st) for st in FIT_STAGES[cfg.method]]
    if lam[0] is not None:  # absent at none (the recipe's), the value before the option existed
        s["lambda_dssim"] = lam[0] if len(set(lam)) == 1 else lam  # one weight: a number, as before per-stage weights
    if cfg.grad_threshold_scale != 1:  # absent at 1, the value before the option existed
        s["grad_threshold_scale"] = cfg.grad_threshold_scale
    if cfg.method == "reings":  # the baselines ignore both; keys absent when off (older folders resume)
        if cfg.view_warp:
            s["view_warp"], s["view_warp_disparity"] = cfg.view_warp, cfg.view_warp_disparity
            start = view_warp_start_of(cfg, family)
            if abs(start - VIEW_WARP_START) > 1e-12:  # the value the fits use; absent at the value before the option existed
                s["view_warp_start"] = start
            if cfg.view_warp_every != 1:  # absent at 1, the value before the option existed
                s["view_warp_every"] = int(cfg.view_warp_every)
            if cfg.view_warp_scale != 1:  # absent at 1, the value before the option existed
                s["view_warp_scale"] = int(cfg.view_warp_scale)
        if cfg.opacity_decay is not None:
            s["opacity_decay"] = cfg.opacity_decay
        if prune_unseen_of(cfg, family):  # absent when off (older folders resume)
            s["prune_unseen"] = True
        cross = cross_warp_of(cfg, family)
        if cross:  # the cross-view photometric term, the value the fits use: absent when off (older folders resume)
            s["cross_warp"] = cross
            if cfg.cross_warp_start:
                s["cross_warp_start"] = cfg.cross_warp_start
            if cfg.cross_warp_occlusion:
                s["cross_warp_occlusion"] = cfg.cross_warp_occlusion
            if cfg.cross_warp_blur:  # its blur levels: absent without (older folders resume)
                s["cross_warp_blur"] = list(cfg.cross_warp_blur)
    if auto_seeds and (cfg.extent == "stereo" or cfg.holdout != "protocol" or cfg.views <= 2):
        s["stereo_seeds"] = "auto"  # seeds where runs before the option had none (stereo_seeds_of)
    if soft_depth_shared_of(cfg, family):
        s["soft_depth_shared"] = True
    drop = drop_gamma_of(cfg, family)
    if drop:  # the value the fits use; absent when off (older folders resume)
        s["drop_gamma"] = drop
    metric = depth_metric_of(cfg, family)
    if metric:  # as drop_gamma
        s["depth_metric"] = metric
    if cfg.holdout != "protocol":
        s["holdout"], s["views"] = cfg.holdout, None  # every view given trains
    if cfg.seed:  # the seed reaches every fit too (before, only the initial points and IVPS/CVPS draws)
        s["fit_seed"] = cfg.seed
    k = ensemble_of(cfg, family)
    if k > 1:  # absent for one model (older folders resume); the first stage of the method recorded as "init"
        s["ensemble"] = k
        s["ensemble_from"] = "init" if ensemble_split(cfg.method, cfg.ensemble_from) == 0 else cfg.ensemble_from
    return s
# }}}


# {{{ the fits' recipes

def recipe_family(recipe: str, dataset_kind: str) -> str:
    """The recipe family of a run's fits: RunConfig.recipe, with "auto" -> "dtu" for DTU scenes
    (DNGaussian trains DTU with its own recipe, docs/method.md §2.2), else "llff"."""
    if recipe != "auto":
        return recipe
    return "dtu" if dataset_kind == "dtu" else "llff"


OPACITY_DECAY_BY_FAMILY = {"llff": 1.0, "dtu": 0.995}  # RunConfig.opacity_decay = none (docs/results.md §9)
# RunConfig.drop_gamma = none, reings fits (docs/results.md §19): DTU scan24, full schedule, H100,
# seeds 0-2: 3 views 16.89 -> 18.54 dB (gamma 0.3: 18.78, 0.4: 18.29, inside the seed spread of
# 0.2's), 2 views 15.31 -> 17.31, 4 views 18.12 -> 19.80. LLFF (§20, with prune_unseen, fern +
# flower, seeds 0-2): 2 views 19.79 -> 20.74, 3 views 20.96 -> 21.68, 4 views 22.39 -> 23.09; without
# prune_unseen 2 of 6 flower runs at 3 views collapsed in the final stage (17.3 / 17.6 dB)
DROP_GAMMA_BY_FAMILY = {"llff": 0.2, "dtu": 0.2}
# The recipe family's rules of a reings fit WITHOUT a depth prior (--depth-prior none), where they differ
# from the rules above (docs/results.md §25; LLFF fern + flower, full schedule, seeds 0-2, NVIDIA H200):
# the cross-view term at 0.15 (not 0.1), the binocular view_warp term from 1/3 of each fit (not 2/3:
# without a prior the coarse and fine fits have no other geometric term) and DropGaussian at 0.3 (not
# 0.2), together: 2 views 19.27 -> 19.58 dB, 3 views 21.24 -> 21.46, 4 views 23.05 -> 23.04 (LPIPS
# 0.311 -> 0.305, 0.246 -> 0.248, 0.186 -> 0.197). Held-out check on trex and room: §25. DTU has no
# measured no-prior rules (its prior is worth +1.9 dB, §22), so it keeps its family's.
# The cross-view term is a no-prior rule only (below): off with any prior, on DTU and for the baselines.
# "lambda_dssim": the SSIM weight per reings fitting stage (coarse, fine, final) since session 18 (docs/results.md
# §28): 0.4 in the fine and final fits, the coarse fit (where the geometry forms) keeping the recipe's 0.2;
# fern + flower, seeds 0-2, LPIPS 0.3045 / 0.2475 / 0.1965 -> 0.2775 / 0.2235 / 0.176 at 2 / 3 / 4 views,
# PSNR -0.09 / +0.01 / -0.27 dB; the held-out NeX trex and room at 2 views -0.01 / +0.01 dB, LPIPS -0.011 /
# -0.008. 0.4 in the coarse fit too made trex's densification run away (§27)
NO_PRIOR_BY_FAMILY = {"llff": {"cross_warp": 0.15, "drop_gamma": 0.3, "view_warp_start": 1 / 3,
                               "lambda_dssim": (0.2, 0.4, 0.4), "fit_scale": (1, 1, 1)}, "dtu": {}}
VIEW_WARP_START = 2 / 3  # the view_warp term's start (Binocular3DGS: 2/3 of the schedule)
# RunConfig.prune_unseen = none, reings fits (§20): on for LLFF (no collapse in 27 runs with the
# drop; alone at 3 views: fern +0.00, flower +0.04 dB, seed 0); not measured on DTU, so off there
PRUNE_UNSEEN_BY_FAMILY = {"llff": True, "dtu": False}
# RunConfig.hard_depth_scale = none: the reings fits' hard depth pass at 1/2 resolution with the patches' scene area
# ('area') for the LLFF family since session 38 (fern / flower / room, 3 views, seeds 0-2 on an H200: -0.06 / +0.15 /
# +0.29 dB paired against 1; trex, held out: +0.01; docs/results.md §49); DTU's recipe gates its soft term on the
# hard loss, not measured at 2: 1
HARD_DEPTH_SCALE_BY_FAMILY = {"llff": 2, "dtu": 1}
# RunConfig.fit_scale = none: the reings fits' resolution divisors (coarse, fine, final). LLFF since session 41: the
# coarse fit at 1/2 (H200, full schedule, seeds 0-2, against 1,1,1: fern / flower / room / trex (held out) at 3 views
# +0.00 / +0.03 / +0.25 / -0.12 dB, fern / flower at 2 views +0.09 / -0.12, the fast preset fern / flower / room
# -0.09 / +0.13 / +0.02; fern's coarse fit 468.5 -> 236.3-279.6 s on 2 Xeon cores; docs/results.md §52). The fine fit
# at 1/2 too (2,2,1) cost trex 0.41 dB, the coarse at 1/4 (4,1,1) flower 2.5 dB (seed 0). DTU, and runs without a
# depth prior (NO_PRIOR_BY_FAMILY): not measured, 1
FIT_SCALE_BY_FAMILY = {"llff": (2, 1, 1), "dtu": (1, 1, 1)}
DROP_METHODS = ("reings", "dngaussian")  # the methods whose fits take RunConfig.drop_gamma
DEPTH_METRIC_BY_FAMILY = {"llff": 0.0, "dtu": 0.0}  # RunConfig.depth_metric = none: off until measured
# RunConfig.cross_warp = none, reings fits with --depth-prior none (docs/results.md §24; the term:
# docs/method.md §12): LLFF fern + flower, full schedule, seeds 0-2, NVIDIA: weight 0.1 takes
# 2 views 18.42 -> 19.27 dB, 3 views 21.16 -> 21.24, 4 views 22.91 -> 23.05; 0.3 collapsed one
# flower run (10.7 dB). DTU scan24 (stereo prior): 0.1 costs 1.0 dB (18.54 -> 17.53), so off for
# 'dtu'; with a depth prior on LLFF not measured, so off with any prior
# 0.15 since §25 (with the no-prior rules above: 2 views 19.27 -> 19.58 dB): NO_PRIOR_BY_FAMILY's "cross_warp"
# the stereo prior's settings per recipe family (docs/results.md §15): DTU's training views are
# ~35 degrees apart, where the plane sweep's matches are ambiguous (brick, windows) and only a much
# stronger SGM smoothness and each view's own near/far hold; LLFF keeps the settings it was measured with
STEREO_BY_FAMILY = {"llff": {}, "dtu": {"sgm_p1": 0.2, "sgm_p2": 9.6, "use_bounds": True}}


# RunConfig.ensemble = none, reings fits: the members per recipe family (docs/results.md §36; H100, full schedule,
# seeds 0-2, members independent): DTU scan24 2 / 3 / 4 views 17.62 / 18.59 / 19.97 -> 17.99 / 19.19 / 20.53 dB
# (LPIPS 0.289 / 0.267 / 0.246 -> 0.279 / 0.255 / 0.233) at twice the training time; LLFF fern + flower at 3
# views +0.35 dB (21.73 -> 22.08), but LLFF already meets its goals and issue 15 times its runs: one model there
ENSEMBLE_BY_FAMILY = {"llff": 1, "dtu": 2}
MEMBER_SEED_STRIDE = 1_000_003  # member k's seed: seed + k * stride (distinct from every other run's seeds < stride)


def ensemble_of(cfg: RunConfig, family: str) -> int:
    """The run's ensemble members: RunConfig.ensemble, or for none the recipe family's for reings
    (its ablations too) and 1 for the baselines."""
    if cfg.ensemble is not None:
        return int(cfg.ensemble)
    return ENSEMBLE_BY_FAMILY[family] if cfg.method == "reings" else 1


def member_seed(seed: int, k: int) -> int:
    """The seed of ensemble member k (member 0: the run's seed)."""
    return int(seed) + int(k) * MEMBER_SEED_STRIDE


def ensemble_split(method: str, start: str) -> int:
    """The index in `stages_of(method)` of the first stage the members do not share (`start`:
    RunConfig.ensemble_from; 'init' = 0, nothing shared)."""
    from .config import STAGES

    return 0 if start == "init" else STAGES[method].index(start)


def prior_for_family(prior, family: str):
    """`prior` with its family's settings (STEREO_BY_FAMILY) when it is the stereo prior and the
    user gave it none of its own."""
    opts = STEREO_BY_FAMILY.get(family, {})
    if getattr(prior, "kind", None) == "stereo" and opts and not prior.options:
        return prior.with_options(**opts)
    return prior


def opacity_decay_of(decay: float | None, family: str) -> float:
    """The reings fits' opacity decay factor: RunConfig.opacity_decay, or for none the recipe
    family's (1 = off)."""
    return OPACITY_DECAY_BY_FAMILY[family] if decay is None else float(decay)


def drop_gamma_of(cfg: RunConfig, family: str) -> float:
    """The DropGaussian gamma of the run's fits (LossConfig.drop_gamma): RunConfig.drop_gamma, or for
    none the recipe family's (DROP_GAMMA_BY_FAMILY) for reings and 0 for the dngaussian baseline (it
    keeps DNGaussian's recipe unless asked); 0 for a method outside DROP_METHODS."""
    if cfg.method not in DROP_METHODS:
        return 0.0
    if cfg.drop_gamma is None:
        if cfg.method != "reings":
            return 0.0
        return _no_prior_rule(cfg, family, "drop_gamma", DROP_GAMMA_BY_FAMILY[family])
    return float(cfg.drop_gamma)


def _no_prior_rule(cfg: RunConfig, family: str, name: str, default):
    """NO_PRIOR_BY_FAMILY[family][name] for a fit without a depth prior that has the rule, else `default`."""
    if prior_kind(cfg.depth_prior) in NO_PRIOR:
        return NO_PRIOR_BY_FAMILY[family].get(name, default)
    return default


def lambda_dssim_of(cfg: RunConfig, family: str, stage: str | None = None) -> float | None:
    """The SSIM weight of the run's fit `stage` (a FIT_STAGES name; none: the last): RunConfig.lambda_dssim
    (`RunConfig.stage_lambda_dssim`), or for none the recipe family's no-prior rule for the reings fits
    (NO_PRIOR_BY_FAMILY, one weight per fitting stage); None: the recipe's."""
    if cfg.lambda_dssim is not None:
        return cfg.stage_lambda_dssim(stage)
    rule = _no_prior_rule(cfg, family, "lambda_dssim", None) if cfg.method == "reings" else None
    return None if rule is None else stage_value(rule, stage)


def view_warp_start_of(cfg: RunConfig, family: str) -> float:
    """Where the view_warp term starts in each reings fit, as a fraction of its iterations:
    RunConfig.view_warp_start, or for none 2/3 (VIEW_WARP_START), 1/3 for a family whose no-prior
    rules say so (NO_PRIOR_BY_FAMILY) in a run without a depth prior."""
    if cfg.view_warp_start is None:
        return _no_prior_rule(cfg, family, "view_warp_start", VIEW_WARP_START)
    return float(cfg.view_warp_start)


def prune_unseen_of(cfg: RunConfig, family: str) -> bool:
    """Whether the run's reings fits drop the Gaussians no training pixel blends at each
    densification (DensifyConfig.prune_unseen): RunConfig.prune_unseen, or for none the recipe
    family's (PRUNE_UNSEEN_BY_FAMILY); never for the baselines."""
    if cfg.method != "reings":
        return False
    return PRUNE_UNSEEN_BY_FAMILY[family] if cfg.prune_unseen is None else bool(cfg.prune_unseen)


def hard_depth_scale_of(cfg: RunConfig, family: str) -> int:
    """The hard depth pass's resolution divisor in the run's fits (LossConfig.hard_depth_scale):
    RunConfig.hard_depth_scale, or for none the recipe family's for the reings fits
    (HARD_DEPTH_SCALE_BY_FAMILY; 1 without a depth prior, where no hard pass runs) and 1 for the baselines
    (their authors' recipes)."""
    if cfg.hard_depth_scale is not None:
        return int(cfg.hard_depth_scale)
    if cfg.method != "reings" or prior_kind(cfg.depth_prior) in NO_PRIOR:  # no prior: no hard pass to scale
        return 1
    return HARD_DEPTH_SCALE_BY_FAMILY[family]


def fit_scale_of(cfg: RunConfig, family: str, stage: str | None) -> int:
    """The resolution divisor of the run's fit `stage` (a FIT_STAGES name): RunConfig.fit_scale, or for
    none the recipe family's (FIT_SCALE_BY_FAMILY; without a depth prior its no-prior rule, NO_PRIOR_BY_FAMILY:
    1 for 'llff', not measured there), for the reings fits; 1 for the baselines and stage none."""
    if cfg.method != "reings" or stage not in FIT_STAGES["reings"]:
        return 1
    scales = cfg.fit_scale
    if scales is None:
        scales = _no_prior_rule(cfg, family, "fit_scale", FIT_SCALE_BY_FAMILY[family])
    return int(stage_value(scales, stage))


def fit_scale_share_of(cfg: RunConfig, stage: str | None) -> float:
    """The share of fit `stage`'s iterations at its fit scale (RunConfig.fit_scale_share; none: 1)."""
    if cfg.fit_scale_share is None or cfg.method != "reings" or stage not in FIT_STAGES["reings"]:
        return 1.0
    return float(stage_value(cfg.fit_scale_share, stage))


def scaled_views(train, priors, confidences, scale: int):
    """The training views, depth priors and their confidences at 1/scale resolution (a fit at
    RunConfig.fit_scale): [(image, camera)] with each image averaged over scale x scale blocks and the
    camera's intrinsics divided by scale (`train.depth_pass_camera`, `train.block_mean`); the priors
    and confidences averaged as the images (None entries and lists kept as they are)."""
    from .train import block_mean, depth_pass_camera

    views = [(block_mean(im, scale), depth_pass_camera(cam, scale, "fit_scale"))
             for im, cam in zip(train.images, train.cameras)]

    def pooled(maps):
        return None if maps is None else [None if m is None else block_mean(m, scale) for m in maps]

    return views, pooled(priors), pooled(confidences)


def soft_depth_shared_of(cfg: RunConfig, family: str) -> bool:
    """Whether the run's fits take the soft depth term on the photometric render
    (LossConfig.soft_depth_shared): RunConfig.soft_depth_shared, or for none the preset's for the
    reings fits of the recipe family `family` (RunPreset.soft_depth_shared: fast and paper for both
    families, quick for none) and off for the baselines (their recipes)."""
    if cfg.soft_depth_shared is not None:
        return bool(cfg.soft_depth_shared)
    return cfg.method == "reings" and family in RUN_PRESETS[cfg.preset].soft_depth_shared


def depth_metric_of(cfg: RunConfig, family: str) -> float:
    """The metric depth term's weight in the run's reings fits (LossConfig.depth_metric):
    RunConfig.depth_metric, or for none the recipe family's (DEPTH_METRIC_BY_FAMILY); 0 for other
    methods and for priors whose depth is not metric (config.METRIC_PRIORS)."""
    from .config import METRIC_PRIORS
    from .data.depth_prior import prior_kind

    if cfg.method != "reings" or prior_kind(cfg.depth_prior) not in METRIC_PRIORS:
        return 0.0
    return DEPTH_METRIC_BY_FAMILY[family] if cfg.depth_metric is None else float(cfg.depth_metric)


def cross_warp_of(cfg: RunConfig, family: str) -> float:
    """The cross-view photometric term's weight in the run's reings fits (LossConfig.cross_warp):
    RunConfig.cross_warp, or for none the recipe family's no-prior rule (NO_PRIOR_BY_FAMILY) without
    a depth prior and 0 with one; 0 for the baselines."""
    if cfg.method != "reings":
        return 0.0
    if cfg.cross_warp is None:
        return _no_prior_rule(cfg, family, "cross_warp", 0.0)
    return float(cfg.cross_warp)


def baseline_recipe(method: str, iters: int, sh_degree: int, family: str = "llff"):
    """The TrainConfig of a baseline fit (and the base of the ReInGS fits): 3DGS's, with
    densification until half the schedule, or DNGaussian's recipe of `family` ("llff" | "dtu");
    squeezed to `iters`."""
    from .config import preset

    if method == "3dgs":
        base = preset("3dgs")
        base = replace(base, densify=replace(base.densify, densify_until=base.iterations // 2))
    else:
        base = preset({"llff": "dngaussian", "dtu": "dngaussian_dtu"}[family])
    return replace(with_iterations(base, iters), sh_degree=sh_degree)


def coarse_recipe(iters: int, sh_degree: int, hard_opacity: float, family: str = "llff"):
    """The coarse ReInGS fit: DNGaussian's recipe, hard depth only at the IVPS opacity."""
    c = baseline_recipe("dngaussian", iters, sh_degree, family)
    return replace(c, loss=replace(c.loss, hard_depth_opacity=hard_opacity, soft_depth=False))


def soft_depth_recipe(iters: int, sh_degree: int, family: str = "llff"):
    """The fine and final ReInGS fits: DNGaussian's recipe with soft depth only (paper Eq. 9), no
    clean_views (their initial points come from the training views). Without the hard pass there
    is no hard loss to gate the soft term on (the DTU recipe's EMA gate), so the gate is off."""
    c = baseline_recipe("dngaussian", iters, sh_degree, family)
    c = replace(c, loss=replace(c.loss, soft_depth_ema_gate=None))
    return replace(c, loss=replace(c.loss, hard_depth=False), densify=replace(c.densify, clean_views=False))
# }}}


# {{{ the run context

class RunContext:
    """What the stages share: the resolved config, the training views and priors, the scene box,
    the device, the random generator, the clock, and the records that become metrics.json."""

    bg, near = (0.0, 0.0, 0.0), 0.01
    in_memory = False  # the scene came from reings.run(scene=...), not from a folder
    prior_options = None  # the stereo prior's options, where the spec or the recipe set some
    member_index = 0  # which ensemble member this context fits (`member`)

    def __init__(self, cfg: RunConfig, backend, train, test, priors, box, log, progress, family: str = "llff"):
        self.cfg, self.backend, self.train, self.test, self.priors, self.box = cfg, backend, train, test, priors, box
        self.confidences = None  # the priors' per-view confidence maps, when the prior has them (_prepare)
        self.family = family  # the fits' recipe family (recipe_family)
        self.device = cfg.device
        self.log, self.progress = log, progress
        self.iterations = cfg.stage_iterations()
        self.extent = scene_extent(train.cameras)  # the learning-rate scale of the means
        self.near_depth = None  # near_prune's scale: the scene's near depth from the box's points
        if cfg.near_prune is not None and cfg.method == "reings":
            self.near_depth = near_depth(train.cameras, box) if box is not None else None
            if self.near_depth is None:
                log(f"[{cfg.label}] note: --near-prune needs the scene box's points (SfM or the stereo prior's), "
                    f"and this box has none; ignored")
        self.rng = np.random.default_rng(cfg.seed)
        # the smoothness weight of every fit: as given, else the recipe's, except with the stereo
        # prior (no measured benefit: RunConfig.depth_smooth)
        self.smooth_w = (cfg.depth_smooth if cfg.depth_smooth is not None
                         else 0.0 if prior_kind(cfg.depth_prior) == "stereo" else None)  # None: the recipe's
        self.g = self.unpruned = None
        self.timings, self.counts, self.model_bytes = {}, {}, {}
        self.stages, self.series, self.bounds = [], [], []
        self.clock = {"train": 0.0, "wall": 0.0, "probe": 0.0}  # cumulative across stages
        self._omega = None
        self.kernel_builds = None  # builds_since the run's start (_run_prepared), for metrics.json

    def run_recipe(self, recipe, stage: str | None = None, fit_scale: int | None = None):
        """A stage's recipe with the run's settings: its seed, the Gaussian cap, the smoothness
        weight, the SSIM weight of fitting stage `stage` (`lambda_dssim_of`; none: the last), the
        densification threshold's scale, the binocular terms (reings fits), DropGaussian (reings and
        dngaussian fits), the metric depth term (reings fits), the DTU background rules; the settings of a fit
        at 1/`fit_scale` resolution (none: the stage's, `fit_scale_of`)."""
        c = self.cfg
        recipe = replace(recipe, seed=c.seed)
        if c.max_gaussians:
            recipe = replace(recipe, densify=replace(recipe.densify, max_gaussians=c.max_gaussians))
        if self.smooth_w is not None:
            recipe = replace(recipe, loss=replace(recipe.loss, depth_smooth_weight=self.smooth_w))
        if c.depth_confidence:
            recipe = replace(recipe, loss=replace(recipe.loss, depth_confidence=c.depth_confidence))
        fs = fit_scale_of(c, self.family, stage) if fit_scale is None else fit_scale  # the fit's views at 1/fs
        # (`fit`): the hard pass's scale over fs
        hd = max(1, hard_depth_scale_of(c, self.family) // fs)
        if hd != 1:
            recipe = replace(recipe, loss=replace(recipe.loss, hard_depth_scale=hd,
                                                  hard_depth_patches=c.hard_depth_patches))
        if fs != 1:
            recipe = replace(recipe, loss=replace(recipe.loss, depth_patch_div=fs))
        if c.off_frame_margin is not None and c.method == "reings":
            recipe = replace(recipe, densify=replace(recipe.densify, off_frame_margin=c.off_frame_margin))
        if c.near_prune is not None and c.method == "reings" and self.near_depth is not None:
            recipe = replace(recipe, densify=replace(recipe.densify, near_prune_radius=c.near_prune * self.near_depth))
        if c.max_screen_fraction and c.method == "reings":  # in the fit's own pixels
            d = recipe.densify
            side = max(max(cam.width, cam.height) for cam in self.train.cameras) / fs
            recipe = replace(recipe, densify=replace(
                d, max_screen_size=c.max_screen_fraction * side,
                size_prune_from=d.densify_from if d.size_prune_from is None else d.size_prune_from,
                max_world_size=None if d.size_prune_from is None else d.max_world_size))
        lam = lambda_dssim_of(c, self.family, stage)  # stage none: the one weight, or the last of three
        if lam is not None:
            recipe = replace(recipe, loss=replace(recipe.loss, lambda_dssim=lam))
        if c.grad_threshold_scale != 1:
            recipe = replace(recipe, densify=replace(
                recipe.densify, grad_threshold=recipe.densify.grad_threshold * c.grad_threshold_scale))
        if soft_depth_shared_of(c, self.family):
            recipe = replace(recipe, loss=replace(recipe.loss, soft_depth_shared=True))
        drop = drop_gamma_of(c, self.family)
        if drop:
            recipe = replace(recipe, loss=replace(recipe.loss, drop_gamma=drop))
        metric = depth_metric_of(c, self.family)
        if metric:
            recipe = replace(recipe, loss=replace(recipe.loss, depth_metric=metric))
        if c.method == "reings":
            recipe = self.binocular(recipe, fs)
            cross = cross_warp_of(c, self.family)
            if cross:  # docs/method.md §12
                start = max(1, int(round(c.cross_warp_start * recipe.iterations)))
                recipe = replace(recipe, loss=replace(recipe.loss, cross_warp=cross, cross_warp_from=start,
                                                      cross_warp_occlusion=c.cross_warp_occlusion,
                                                      cross_warp_blur=c.cross_warp_blur))
            if prune_unseen_of(c, self.family):
                recipe = replace(recipe, densify=replace(recipe.densify, prune_unseen=True))
        if c.dtu_background:
            recipe = replace(recipe, loss=replace(recipe.loss, dark_background=True),
                             densify=replace(recipe.densify, dark_white_rules=True))
        return recipe

    def binocular(self, recipe, fit_scale: int = 1):
        """`recipe` with the run's view_warp term and opacity decay (reings fits): the largest
        baseline from view_warp_disparity pixels at the scene's typical depth, the start at
        `view_warp_start_of` (the resolved view_warp_start) of the fit's iterations, the term's
        resolution divisor over the fit's own (`fit_scale`, at least 1)."""
        c = self.cfg
        if c.view_warp:
            vs = max(1, int(c.view_warp_scale) // fit_scale)
            if vs != 1:
                recipe = replace(recipe, loss=replace(recipe.loss, view_warp_scale=vs))
            b = c.view_warp_disparity * typical_depth(self.train.cameras, self.box) / np.mean(
                [cam.fx for cam in self.train.cameras])
            start = max(1, int(round(view_warp_start_of(c, self.family) * recipe.iterations)))
            recipe = replace(recipe, loss=replace(recipe.loss, view_warp_weight=c.view_warp, view_warp_baseline=b,
                                                  view_warp_from=start,
                                                  view_warp_every=int(c.view_warp_every)))
        decay = opacity_decay_of(c.opacity_decay, self.family)
        if decay != 1:
            recipe = replace(recipe, densify=replace(recipe.densify, opacity_decay=decay))
        return recipe

    def checkpoint(self, name: str):
        out = self.cfg.output.out
        prefix = f"member{self.member_index}_" if self.member_index else ""
        return os.path.join(out, "checkpoints", prefix + name + ".npz") if out else None

    def member(self, k: int, g):
        """Ensemble member k >= 1: this context's inputs (views, priors, box, device, config) with
        the member's seed (`member_seed`: its fits' seed and a fresh random generator), its own
        checkpoints and records, starting from `g` (the shared stages' model; None when nothing
        is shared)."""
        m = copy.copy(self)
        m.cfg = replace(self.cfg, seed=member_seed(self.cfg.seed, k))
        m.member_index = k
        m.rng = np.random.default_rng(m.cfg.seed)
        m.g, m.unpruned, m._omega = g, None, None
        m.timings, m.counts, m.model_bytes = {}, {}, {}
        m.stages, m.series, m.bounds = [], [], []
        m.clock = {"train": 0.0, "wall": 0.0, "probe": 0.0}
        m.log = lambda msg, _log=self.log: _log(f"(member {k}) {msg}")
        return m

    def probe(self, g) -> dict:
        t0 = time.perf_counter()
        v = test_psnr(g, self.test, self.device, self.bg, self.near)
        dt = time.perf_counter() - t0
        self.clock["probe"] += dt
        return {"psnr": v, "eval_seconds": dt}

    def importance(self, g) -> np.ndarray:
        """Omega_G of `g` over the training views (computed once per model)."""
        if self._omega is None or self._omega[0] is not g:
            self._omega = (g, gaussian_importance(g, self.train.cameras, self.device, self.bg, self.near))
        return self._omega[1]

    def random_init(self):
        """`init_points` uniform points in the scene box, DNGaussian's near-grey colours."""
        pts = random_points_in_box(self.box.lo, self.box.hi, self.cfg.init_points, self.rng)
        return gaussians_from_points(pts, None, self.cfg.sh_degree, self.rng)

    def record(self, name: str, g, seconds: float, on_clock: bool = True, **extra):
        """The records of a stage that does not fit: seconds (on the method clock unless
        on_clock=False), Gaussian count and bytes, an entry in metrics.json `stages`, a log line."""
        if on_clock:
            self.clock["train"] += seconds
            self.clock["wall"] += seconds
        self.timings[name] = seconds
        self.counts[name] = len(g)
        self.model_bytes[name] = gaussians_nbytes(g)
        self.stages.append({"stage": name, "iterations": 0, "seconds": seconds, "wall_seconds": seconds,
                            "eval_seconds": 0.0, "gaussians": len(g), "model_bytes": self.model_bytes[name],
                            "peak_rss_mb": _peak_rss_mb(), "device_peak_bytes": device_peak_bytes(self.backend),
                            **extra})
        before = "" if self.g is None else f"{len(self.g)} -> "
        self.log(f"[{self.cfg.label}] {name}: {before}{len(g)} Gaussians, {seconds:.2f} s")
        return g

    def fit(self, name: str, recipe, init, use_priors: bool):
        """One fitting stage: `recipe` with the run's seed and overrides, from `init`; its probes
        join the PSNR-vs-seconds series, its seconds (probes excluded) the method clock."""
        c = self.cfg
        base, recipe = recipe, self.run_recipe(recipe, name)
        ee = auto_eval_every(recipe.iterations) if c.output.eval_every is None else c.output.eval_every
        if not self.series and ee:  # the starting point of the curve: the initial Gaussians
            self.series.append({"stage": "init", "iteration": 0, "seconds": 0.0, "wall_seconds": 0.0,
                                **self.probe(init)})
        prof = {} if c.output.profile else None  # phase -> wall seconds (Trainer.phase)
        built = kernel_builds(self.backend)
        views, priors, conf = self.train, self.priors, self.confidences
        fs, lead = fit_scale_of(c, self.family, name), None
        if fs != 1:
            views, priors, conf = scaled_views(self.train, priors, conf, fs)
            until = max(1, int(round(fit_scale_share_of(c, name) * recipe.iterations)))
            if until < recipe.iterations:  # its first iterations at 1/fs, the rest at full resolution
                lead = FitLead(until, views, recipe.loss, priors if use_priors else None,
                               conf if use_priors else None, recipe.densify)
                recipe = self.run_recipe(base, name, fit_scale=1)
                views, priors, conf = self.train, self.priors, self.confidences
        r = fit(views, recipe, device=self.device, init=init, lead=lead,
                depth_targets=priors if use_priors else None, progress=self.progress,
                depth_confidence=conf if use_priors else None,
                checkpoint=self.checkpoint(name), checkpoint_every=c.output.checkpoint_every,
                checkpoint_seconds=c.output.checkpoint_seconds,
                eval_fn=self.probe if ee else None, eval_every=ee, desc=name, extent=self.extent, profile=prof)
        # history.eval: (iteration, seconds since this fit's start taken before the probe ran,
        # {"psnr", "eval_seconds"}); restored from the checkpoint on resume
        before, start = 0.0, dict(self.clock)
        for it, sec, m in (tuple(e) for e in r.history.eval):
            self.series.append({"stage": name, "iteration": int(it), "seconds": start["train"] + float(sec) - before,
                                "wall_seconds": start["wall"] + float(sec), "psnr": m.get("psnr"),
                                "eval_seconds": m.get("eval_seconds")})
            before += float(m.get("eval_seconds") or 0.0)
        train_s = max(float(r.seconds) - before, 0.0)
        self.clock["train"] += train_s
        self.clock["wall"] += float(r.seconds)
        self.bounds.append({"stage": name, "start": start["train"], "end": self.clock["train"]})
        g = r.gaussians
        self.timings[name] = train_s
        self.counts[name] = len(g)
        self.model_bytes[name] = gaussians_nbytes(g)
        self.stages.append({"stage": name, "iterations": recipe.iterations, "seconds": train_s,
                            "wall_seconds": float(r.seconds), "eval_seconds": before, "eval_every": ee,
                            "checkpoints": r.checkpoints,
                            "gaussians": len(g), "model_bytes": self.model_bytes[name],
                            "peak_rss_mb": _peak_rss_mb(), "device_peak_bytes": device_peak_bytes(self.backend),
                            "config": recipe.to_dict(), "history": r.history.to_dict(),
                            **({"lead": {"until": lead.until, "fit_scale": fs,  # its first iterations at 1/fs
                                         "config": replace(recipe, loss=lead.loss, densify=lead.densify).to_dict()}}
                               if lead is not None else {}),
                            "kernel_builds": builds_since(self.backend, built), "kernel_builds_on_clock": r.kernel_builds,
                            **({"phases": {k: v for k, v in prof.items() if k != "device_ms"}} if prof is not None else {})})
        last = f", test PSNR {self.series[-1]['psnr']:.2f}" if self.series and self.series[-1]["stage"] == name else ""
        self.log(f"[{c.label}] {name}: {recipe.iterations} its, {train_s:.1f} s, {len(g)} Gaussians{last}")
        return g
# }}}


# {{{ the stages: f(ctx, name) -> the next Gaussians

def stage_init(ctx: RunContext, name: str):
    """Random initial points in the scene box (initialisation: not on the method clock)."""
    t = time.perf_counter()
    g = ctx.random_init()
    ctx.counts["init"], ctx.model_bytes["init"] = len(g), gaussians_nbytes(g)
    return ctx.record(name, g, time.perf_counter() - t, on_clock=False)


# measured (docs/results.md §16, H100, full schedule, seeds 0-2): at 2 views LLFF fern 18.87 -> 20.12 dB,
# flower 19.26 -> 19.47, DTU scan24 (no SfM points: the stereo box) 10.22 -> 15.31; at 3 views DTU
# scan24 16.89 -> 16.67 (inside the seed spread) and LLFF not yet measured: so on at 2 views and
# wherever SfM failed, off otherwise
STEREO_SEEDS_AUTO = 0.1


def stereo_seeds_of(rc: ReInGSConfig, box, n_views: int, preset: float | None = None) -> float:
    """The fraction of seeded pixels: as set, else the run preset's (`preset`, RunPreset.stereo_seeds)
    if it has one, else STEREO_SEEDS_AUTO at 2 training views or when the box is the stereo
    prior's (SfM found too few points), else 0."""
    if rc.stereo_seeds is not None:
        return rc.stereo_seeds
    if preset is not None:
        return preset
    return STEREO_SEEDS_AUTO if n_views <= 2 or getattr(box, "method", None) == "stereo" else 0.0


def stage_ehps(ctx: RunContext, name: str):
    """EHPS initial points (paper §3.1), or random ones with EHPS off (initialisation: not on the
    method clock)."""
    rc = ctx.cfg.reings
    t = time.perf_counter()
    seeds, frac = None, stereo_seeds_of(rc, ctx.box, len(ctx.train), RUN_PRESETS[ctx.cfg.preset].stereo_seeds)
    if rc.ehps and frac and ctx.priors is not None and ctx.confidences is not None:
        seeds = stereo_seed_points(ctx.train, ctx.priors, ctx.confidences, frac, rc.stereo_seed_conf, ctx.rng)
    g = ehps_init(ctx.box.lo, ctx.box.hi, rc, ctx.cfg.sh_degree, ctx.rng, seeds) if rc.ehps else ctx.random_init()
    ctx.counts["init"], ctx.model_bytes["init"] = len(g), gaussians_nbytes(g)
    return ctx.record(name, g, time.perf_counter() - t, on_clock=False, enabled=rc.ehps,
                      stereo_seeds=0 if seeds is None else len(seeds[0]),
                      stereo_seed_fraction=frac if seeds is not None else 0.0)


def stage_baseline_fit(ctx: RunContext, name: str):
    """The one fit of 3dgs or dngaussian (the stage is named after the method); only DNGaussian's
    recipe has depth terms."""
    recipe = baseline_recipe(name, ctx.iterations[name], ctx.cfg.sh_degree, ctx.family)
    return ctx.fit(name, recipe, ctx.g, use_priors=name == "dngaussian")


def stage_coarse(ctx: RunContext, name: str):
    recipe = coarse_recipe(ctx.iterations[name], ctx.cfg.sh_degree, ctx.cfg.reings.ivps_hard_opacity, ctx.family)
    return ctx.fit(name, recipe, ctx.g, use_priors=True)


def stage_ivps(ctx: RunContext, name: str):
    """IVPS (paper Eq. 4-6): new points drawn from the training views' pixels by the coarse model."""
    rc = ctx.cfg.reings
    t = time.perf_counter()
    g = ctx.g
    if rc.ivps:
        pts, cols = ivps_points(g, ctx.train, ctx.priors, rc, ctx.device, ctx.bg, ctx.near, ctx.rng)
        g = gaussians_from_points(pts, cols, ctx.cfg.sh_degree, ctx.rng)
    return ctx.record(name, g, time.perf_counter() - t, enabled=rc.ivps)


def stage_soft_fit(ctx: RunContext, name: str):
    """The fine and final fits (paper Eq. 9)."""
    return ctx.fit(name, soft_depth_recipe(ctx.iterations[name], ctx.cfg.sh_degree, ctx.family), ctx.g,
                   use_priors=True)


def stage_cvps(ctx: RunContext, name: str):
    """CVPS (paper Eq. 7-8): a draw of the fine Gaussians by Omega_G; their colour (SH DC) is kept,
    the view dependence reset, shapes and opacities re-initialised."""
    rc = ctx.cfg.reings
    t = time.perf_counter()
    g = ctx.g
    if rc.cvps:
        sel = cvps_select(g, ctx.train, rc, ctx.device, ctx.bg, ctx.near, ctx.rng)
        sh = g.sh[sel].copy()
        sh[:, 1:] = 0
        g = dataclasses.replace(gaussians_from_points(g.means[sel], None, ctx.cfg.sh_degree, ctx.rng), sh=sh)
    return ctx.record(name, g, time.perf_counter() - t, enabled=rc.cvps, fraction=rc.cvps_fraction)


def stage_final_prune(ctx: RunContext, name: str):
    """Remove the lowest `final_prune` fraction of the final Gaussians by Omega_G over the TRAINING
    views. Never checkpointed: computed on every (re)run from the final model (final.npz on
    resume), so it is applied exactly once, deterministically (stable ranking, deterministic
    renders). The PSNR-vs-seconds series ends on the pruned model."""
    frac = ctx.cfg.reings.final_prune
    ctx.unpruned = g0 = ctx.g
    if not frac:
        return g0
    t = time.perf_counter()
    g = g0.subset(prune_keep_indices(ctx.importance(g0), 1.0 - frac))
    ctx.record(name, g, time.perf_counter() - t, fraction=frac, gaussians_before=len(g0),
               importance="Omega_G (Eq. 7), alpha*T summed over the training views")
    if ctx.series:
        ctx.series.append({"stage": name, "iteration": 0, "seconds": ctx.clock["train"],
                           "wall_seconds": ctx.clock["wall"], **ctx.probe(g)})
    return g


STAGE_FUNCTIONS = {"init": stage_init, "ehps": stage_ehps, "coarse": stage_coarse, "ivps": stage_ivps,
                   "fine": stage_soft_fit, "cvps": stage_cvps, "final": stage_soft_fit,
                   "final_prune": stage_final_prune, "dngaussian": stage_baseline_fit, "3dgs": stage_baseline_fit}


def stages_of(method: str) -> list:
    """[(name, function)] of a method's stages, in order (names: `reings.config.STAGES`)."""
    from .config import STAGES

    return [(name, STAGE_FUNCTIONS[name]) for name in STAGES[method]]
# }}}


# {{{ run

def _uses_caches(cfg: RunConfig, in_memory: bool) -> bool:
    """Whether the SfM and depth-prior disk caches are read and written: not for in-memory views
    with no output folder (reings.reconstruct: nothing on disk)."""
    return not in_memory or bool(cfg.output.out)


def _check_before_writing(cfg: RunConfig, overwrite: bool, cache: bool = True):
    """Everything a user can get wrong that needs no scene: the data folder, a finished --out, the
    device, the depth prior (`cache`: its disk cache on or off). Returns (backend, depth prior or
    None for 'exact')."""
    from .backends import get_backend
    from .data.depth_prior import get_depth_prior

    if cfg.data is not None and cfg.data != "procedural":
        if not os.path.exists(cfg.data):
            raise FileNotFoundError(f"--data {cfg.data}: scene folder not found")
        if not os.path.isdir(cfg.data):
            raise NotADirectoryError(f"--data {cfg.data}: not a folder")
    out = cfg.output.out
    if out and os.path.exists(os.path.join(out, "metrics.json")) and not overwrite:  # before any work
        raise FileExistsError(f"{out} already holds a finished run (metrics.json); pass --overwrite to redo it")
    _check_extras(cfg)
    backend = get_backend(cfg.device)  # unknown device -> DeviceNotFound, before anything is written
    prior = None if cfg.depth_prior == "exact" else get_depth_prior(cfg.depth_prior, cache=cache)
    return backend, prior


EXTRAS_HINT = "pip install 'reings[data]'"


class MissingExtraError(ValueError):
    """A run needs an optional package that is not installed (one line: which, why, how)."""


def _check_extras(cfg: RunConfig) -> None:
    """The optional packages this run will need, checked before any work (issue 14 item 21):
    OpenCV to read a scene's images or write the renders, onnxruntime for LPIPS when a model is
    there to run (without a model LPIPS is skipped and reported as such)."""
    import importlib.util

    def have(mod: str) -> bool:
        try:
            return importlib.util.find_spec(mod) is not None
        except (ImportError, ValueError):  # a module set to None in sys.modules, a broken install
            return False

    if not have("cv2"):
        if cfg.data not in (None, "procedural"):
            raise MissingExtraError(f"reading the images of --data {cfg.data} needs OpenCV: {EXTRAS_HINT}")
        if cfg.output.out:
            raise MissingExtraError(f"writing the test renders into --out needs OpenCV: {EXTRAS_HINT} "
                                    "(or run without --out)")
    if not cfg.output.lpips:
        return
    from .metrics import LPIPSModelNotFound, find_lpips_model, load_lpips_model

    try:
        path = find_lpips_model()
    except LPIPSModelNotFound:
        if os.environ.get("REINGS_LPIPS_MODEL"):
            raise  # a model named explicitly must be there (the message names it)
        return  # no model on this machine: LPIPS is skipped and reported as such
    if not have("onnxruntime"):
        raise MissingExtraError(f"LPIPS needs onnxruntime: {EXTRAS_HINT}, or pass --no-lpips")
    load_lpips_model(path)  # a model that does not load is an error now, not after the training


def option_notes(cfg: RunConfig, family: str, n_train: int) -> list:
    """The notes on options this run ignores (its method, its training views): only for values
    given, never for a none resolved to the recipe's (cross_warp_of, drop_gamma_of, ...)."""
    notes = []
    if cfg.reings.final_prune > 0 and cfg.method != "reings":
        notes.append("final_prune applies to reings only; ignored")
    if cfg.drop_gamma and cfg.method not in DROP_METHODS:
        notes.append(f"drop_gamma applies to the {' and '.join(DROP_METHODS)} fits only; ignored")
    if cfg.depth_metric and cfg.method != "reings":
        notes.append("depth_metric applies to the reings fits only; ignored")
    if cfg.cross_warp and cfg.method != "reings":
        notes.append("cross_warp applies to the reings fits only; ignored")
    elif cfg.cross_warp and n_train < 2:  # given: the recipe's default needs no note
        notes.append(f"cross_warp needs a partner view: {n_train} training view; ignored")
    if ensemble_of(cfg, family) == 1:
        if cfg.ensemble_from != "init":
            notes.append("ensemble_from without an ensemble (--ensemble K > 1); ignored")
        if cfg.ensemble_jobs > 1:
            notes.append("ensemble_jobs without an ensemble (--ensemble K > 1); ignored")
    for opt_name in ("cross_warp_start", "cross_warp_occlusion", "cross_warp_blur"):
        if getattr(cfg, opt_name) and not (cfg.cross_warp or cross_warp_of(cfg, family)):
            notes.append(f"{opt_name} without cross_warp; ignored")
    if cfg.fit_scale is not None and any(s != 1 for s in cfg.fit_scale) and cfg.method != "reings":
        notes.append("fit_scale applies to the reings fits only; ignored")
    if cfg.fit_scale_share is not None and any(v != 1 for v in cfg.fit_scale_share) and not any(
            fit_scale_of(cfg, family, st) != 1 and fit_scale_share_of(cfg, st) != 1 for st in FIT_STAGES["reings"]):
        notes.append("fit_scale_share applies to the reings fits at a fit scale above 1 only; ignored")
    for opt_name in ("max_screen_fraction", "off_frame_margin", "near_prune"):
        if getattr(cfg, opt_name) is not None and cfg.method != "reings":
            notes.append(f"{opt_name} applies to the reings fits only; ignored")
    if cfg.view_warp_scale != 1 and (cfg.method != "reings" or not cfg.view_warp):
        notes.append("view_warp_scale applies to the reings fits' view_warp term only; ignored")
    return notes


def _prepare(cfg: RunConfig, backend, prior, overwrite: bool, quiet: bool, scene=None):
    """Load (unless `scene` is given) and split the scene, claim the output folder, compute the priors and the scene box:
    (RunContext, settings, scene, train indices, test indices)."""
    from .data.sfm import frusta_only_extent, sfm_extent
    from .data.splits import few_shot_split
    from .io.cameras import write_cameras_json
    from .outputs import check_out, prepare_out, write_config

    timings = {}
    t = time.perf_counter()
    in_memory = scene is not None
    scene = load_run_scene(cfg.data, cfg.dataset, factor=cfg.factor) if scene is None else scene
    if cfg.holdout == "none":  # every view trains; the metrics are on the training views
        if len(scene) < 2:
            raise ValueError(f"{cfg.data or 'the scene'}: --holdout none needs at least 2 views, got {len(scene)}")
        tr_idx, te_idx = list(range(len(scene))), []
        train = scene.subset(tr_idx)
        test = train
    else:
        tr_idx, te_idx = few_shot_split(scene, cfg.views)
        train, test = scene.subset(tr_idx), scene.subset(te_idx)  # training side sees only `train`
    if not len(test):
        raise ValueError(f"{cfg.data or 'procedural'}: the split leaves no test view")
    timings["load"] = time.perf_counter() - t
    if cfg.depth_prior == "exact" and train.depths is None:
        raise ValueError("--depth-prior exact needs a scene with exact depths (the procedural scene)")
    settings = run_settings(cfg, scene.kind)
    family = recipe_family(cfg.recipe, scene.kind)
    if in_memory:  # a resume must find the same images and cameras
        from .data.cachekey import scene_digest

        settings["scene_digest"] = scene_digest(scene)
    if cfg.output.out:  # refusals first, writing nothing: the priors and the box may still fail
        check_out(cfg.output.out, settings, overwrite)
    from .log import logger, progress_enabled

    log = logger.info
    for note in option_notes(cfg, family, len(train)):
        log(f"[{cfg.label}] note: {note}")

    t = time.perf_counter()
    confidences = None  # per view [H, W] in [0, 1] (the stereo prior's) or None
    if cfg.depth_prior == "exact":
        priors = list(train.depths)
    else:
        prior = prior_for_family(prior, family)
        priors, confidences = (prior.compute(train, return_confidence=True) if getattr(prior, "enabled", True)
                               else (None, None))
        if priors is not None and all(p is None for p in priors):
            priors = confidences = None
    if cfg.depth_confidence and (confidences is None or all(c is None for c in confidences)):
        log(f"[{cfg.label}] note: --depth-confidence needs a prior with a confidence (stereo); "
            f"the {cfg.depth_prior!r} prior has none, so the depth loss is unweighted")
    timings["depth_prior"] = time.perf_counter() - t
    t = time.perf_counter()
    if cfg.extent == "stereo":  # the prior's box, asked for
        box = stereo_box(train, priors, confidences, cfg.reings.stereo_seed_conf) if confidences is not None else None
        if box is None:
            raise ValueError(f"{cfg.data or 'the scene'}: --extent stereo: the stereo prior is confident (>= "
                             f"{cfg.reings.stereo_seed_conf}) at fewer than 1000 training pixels; use --extent sfm")
    else:
        box = frusta_only_extent(train) if cfg.extent == "frusta" else sfm_extent(train, cache=_uses_caches(cfg, in_memory))
    # SfM ran and found too few points (box.note empty; "no pycolmap" etc. keep the frusta): the prior's box
    if box.method == "frusta" and cfg.extent == "sfm" and not box.note and confidences is not None:
        sbox = stereo_box(train, priors, confidences, cfg.reings.stereo_seed_conf)
        if sbox is not None:
            log(f"[{cfg.label}] scene box: {box.num_sfm_points} SfM points, so the stereo prior's "
                f"{sbox.n_points} confident points")
            box = dataclasses.replace(sbox, num_sfm_points=box.num_sfm_points, num_matched_pairs=box.num_matched_pairs)
    if box.method == "stereo":  # data-dependent: a resume must find the same box (absent otherwise, as before)
        settings["box"] = "stereo"
    if (cfg.reings.stereo_seeds and cfg.method == "reings" and cfg.reings.ehps
            and (confidences is None or all(c is None for c in confidences))):
        log(f"[{cfg.label}] note: --stereo-seeds needs a prior with a confidence (stereo); the "
            f"{cfg.depth_prior!r} prior has none, so EHPS adds no seeds")
    timings["sfm"] = time.perf_counter() - t
    if cfg.output.out:  # nothing is written before every input has been read and checked
        prepare_out(cfg.output.out, settings, overwrite)
        write_config(cfg.output.out, cfg)
        write_cameras_json(os.path.join(cfg.output.out, "cameras.json"),
                           [("train", train.names, train.cameras)]
                           + ([("test", test.names, test.cameras)] if te_idx else []))
    ctx = RunContext(cfg, backend, train, test, priors, box, log, progress=progress_enabled(quiet), family=family)
    ctx.prior_options = (prior.options or None) if prior_kind(cfg.depth_prior) == "stereo" else None
    ctx.timings.update(timings)
    ctx.confidences = confidences
    ctx.in_memory = in_memory
    return ctx, settings, scene, tr_idx, te_idx


def _metrics(ctx: RunContext, m: dict, settings: dict, scene, tr_idx, te_idx, curve, ensemble=None) -> dict:
    """metrics.json (docs/pipeline.md lists the keys)."""
    cfg, backend, box = ctx.cfg, ctx.backend, ctx.box
    dev_peak = device_peak_bytes(backend)
    cross = cross_warp_of(cfg, ctx.family)  # the cross-view term's weight (recorded only when on)
    if ctx.in_memory:  # reings.run(scene=...) / reings.reconstruct
        scene_name = os.path.basename(os.path.normpath(scene.source)) if scene.source else "in-memory"
    else:
        scene_name = ("procedural" if cfg.data in (None, "procedural")
                      else os.path.basename(os.path.normpath(cfg.data)))
    metrics = {
        "method": cfg.label, "base_method": cfg.method, "scene": scene_name, "dataset": scene.kind,
        "preset": cfg.preset, "views": len(tr_idx), "holdout": cfg.holdout,
        "scored_on": "train" if cfg.holdout == "none" else "test", "device": cfg.device,
        "device_name": getattr(backend, "device_name", cfg.device),
        "data": "in-memory" if ctx.in_memory else cfg.data or "procedural", "train_indices": list(map(int, tr_idx)),
        "test_indices": list(map(int, te_idx if cfg.holdout == "protocol" else tr_idx)), "train_names": list(ctx.train.names),
        "test_names": list(ctx.test.names), "depth_prior": cfg.depth_prior,
        **({"depth_prior_options": ctx.prior_options} if ctx.prior_options else {}), "seed": cfg.seed,
        "sh_degree": cfg.sh_degree, "recipe": ctx.family, "drop_gamma": drop_gamma_of(cfg, ctx.family),
        "depth_metric": depth_metric_of(cfg, ctx.family),
        **({"cross_warp": cross} if cross else {}),
        **({"cross_warp_occlusion": cfg.cross_warp_occlusion} if cross and cfg.cross_warp_occlusion else {}),
        **({"cross_warp_blur": list(cfg.cross_warp_blur)} if cross and cfg.cross_warp_blur else {}),
        "mean": {k: m[k] for k in ("psnr", "ssim", "lpips", "avge") if k in m and m[k] is not None},
        "per_image": m.get("per_image"), "seconds": ctx.timings, "gaussians": ctx.counts,
        "model_bytes": ctx.model_bytes, "peak_rss_mb": _peak_rss_mb(),
        # this process's OpenCL builds during the run (each stage entry has its fit's share): a build is
        # once per process, and pyopencl's and the driver's binary caches make a later process's cheap
        **({"kernel_builds": ctx.kernel_builds} if getattr(ctx, "kernel_builds", None) is not None else {}),
        "memory": {"peak_rss_mb": _peak_rss_mb(), "device_peak_mb": None if dev_peak is None else dev_peak / 2**20,
                   "device_peak_bytes": dev_peak, "binning": binning_of(backend),
                   "model_mb": {k: v / 2**20 for k, v in ctx.model_bytes.items()},
                   "note": "peaks are this process's high-water marks (several runs in one process share them)"},
        "sfm": {"method": box.method, "points": int(box.num_sfm_points), "lo": box.lo, "hi": box.hi,
                "cached": bool(getattr(box, "cached", False)), "note": getattr(box, "note", ""),
                **({"stereo_points": box.n_points} if box.method == "stereo" else {})},
        "psnr_vs_time": {"points": ctx.series, "stages": ctx.bounds,
                         "clock": "seconds = training + re-initialisation wall clock, test-PSNR probes excluded; "
                                  "wall_seconds = the same with the probes"},
        "reings_config": dataclasses.asdict(cfg.reings),
        "config": {**settings, "device": cfg.device, "with_lpips": cfg.output.lpips,
                   "eval_every": cfg.output.eval_every, "checkpoint_every": cfg.output.checkpoint_every,
                   "checkpoint_seconds": cfg.output.checkpoint_seconds,
                   "prune_curve": cfg.output.prune_curve},
        "run_config": dataclasses.asdict(cfg),
        "stages": ctx.stages,
    }
    if curve is not None:
        metrics["prune_curve"] = curve
    if ensemble is not None:
        metrics["ensemble"] = ensemble
    if "lpips_error" in m:
        metrics["lpips_error"] = m["lpips_error"]
    elif m.get("lpips") is not None:  # which network scored LPIPS (path and sha256)
        from .metrics import lpips_model_info

        metrics["lpips_model"] = lpips_model_info()
    return metrics


def run(config: RunConfig | None = None, /, *, scene=None, overwrite: bool = False, quiet: bool = True,
        **keywords) -> RunResult:
    """Fit one scene and evaluate its test views: `run(RunConfig(...))`, or `run(**keywords)` with
    RunConfig's field names and its sections' (`method=`, `views=`, `iterations=`, `out=`,
    `eval_every=`, `cvps_fraction=`, `reings=ReInGSConfig(...)`, ...; see `reings.config.run_config`).

    scene: a `reings.Scene` in memory (images, cameras, names; kind picks the split protocol)
        instead of `data`: nothing is read from disk.
    overwrite: redo a finished run in `out` (its outputs and checkpoints move to
        out/.previous-run, deleted when the new run has finished and put back if it fails);
        without it a folder holding metrics.json is refused, and one holding checkpoints of the
        same settings is resumed. quiet (default): no progress bars; quiet=False draws them when
        stderr is a terminal. Stage lines go to the "reings" logger (reings.log). Neither
        changes the result.
    Returns RunResult(gaussians, metrics, stages, members): `metrics` is what metrics.json holds,
    `stages` its `stages`; `members` every model of an ensemble (`--ensemble K`: gaussians is
    member 0, and the metrics are the members' mean image's), [gaussians] for one model.
    """
    if config is not None and not isinstance(config, RunConfig):
        raise TypeError(f"run(config): expected a RunConfig, got {type(config).__name__} (pass data= by keyword)")
    cfg = run_config(config, **keywords).resolved()  # bad values: ValueError naming the field
    if scene is not None:
        from .data.types import Scene

        if not isinstance(scene, Scene):
            raise TypeError(f"run(scene=...): expected a reings.Scene, got {type(scene).__name__}")
        if cfg.data is not None:
            raise ValueError(f"run: pass either data ({cfg.data!r}) or scene, not both")
    backend, prior = _check_before_writing(cfg, overwrite, cache=_uses_caches(cfg, scene is not None))
    out = cfg.output.out
    try:
        result = _run_prepared(cfg, backend, prior, overwrite, quiet, scene)
    except BaseException:
        if out and overwrite:  # the run --overwrite was to replace comes back (outputs.restore_out)
            from .outputs import restore_out

            restore_out(out)
        raise
    if out:
        from .outputs import finish_out

        finish_out(out)  # the replaced run goes only now that the new one is complete
    return result


def _run_prepared(cfg: RunConfig, backend, prior, overwrite: bool, quiet: bool, scene=None) -> RunResult:
    """`run` after the checks that need no scene: prepare, the stages, scoring, the outputs."""
    from .outputs import jsonable, write_run_outputs, write_test_renders

    t_start = time.perf_counter()
    built = kernel_builds(backend)
    ctx, settings, scene, tr_idx, te_idx = _prepare(cfg, backend, prior, overwrite, quiet, scene)
    stages = stages_of(cfg.method)
    split = ensemble_split(cfg.method, cfg.ensemble_from)
    for name, stage in stages[:split]:  # the stages the members share
        ctx.g = stage(ctx, name)
    k = ensemble_of(cfg, ctx.family)  # member 0 goes on with the run's context and draws: the plain run
    members = fit_members(ctx, stages, split, k, jobs_of(cfg, k))
    ctx.timings["method"] = sum(m.clock["train"] for m in members)  # training + re-initialisation, probes excluded
    ctx.timings["probes"] = sum(m.clock["probe"] for m in members)
    curve = None
    if cfg.output.prune_curve:  # reporting only: the model before final_prune, cut by the same ranking
        t = time.perf_counter()
        g0 = ctx.unpruned if ctx.unpruned is not None else ctx.g
        curve = prune_curve_points(g0, ctx.importance(g0), ctx.test, cfg.device, ctx.bg, ctx.near)
        ctx.timings["prune_curve"] = time.perf_counter() - t

    t = time.perf_counter()
    models, member_preds = [mk.g for mk in members], []
    m, preds, depths = score_test_views(models if len(models) > 1 else ctx.g, ctx.test, cfg.device, ctx.bg, ctx.near,
                                        with_lpips=cfg.output.lpips, per_member=member_preds)
    ensemble = ensemble_record(members, split, stages, ctx.test, member_preds) if len(members) > 1 else None
    out = cfg.output.out
    if out:
        write_test_renders(out, ctx.test.names, preds, depths)
    ctx.timings["eval"] = time.perf_counter() - t
    ctx.timings["total"] = time.perf_counter() - t_start
    ctx.kernel_builds = builds_since(backend, built)
    metrics = jsonable(_metrics(ctx, m, settings, scene, tr_idx, te_idx, curve, ensemble))
    if out:
        write_run_outputs(out, ctx.g, metrics, ctx.series, ctx.bounds,
                          f"{cfg.label} on {metrics['scene']}, {metrics['views']} views ({cfg.device})",
                          members=models[1:])
    return RunResult(ctx.g, metrics, ctx.stages, models)


def ensemble_record(members: list, split: int, stages: list, test, member_preds: list) -> dict:
    """metrics.json `ensemble`: the members, the stages they share, and each member's seed, model
    size, seconds (its own stages; member 0's include the shared ones) and test metrics (PSNR and
    SSIM of its own images `member_preds[k]`, from `score_test_views`: what one model of the
    ensemble scores)."""
    from .metrics import evaluate_images

    ctx = members[0]
    per = []
    for mk, preds in zip(members, member_preds):
        mm = evaluate_images(preds, list(test.images), masks=test.masks, with_lpips=False)
        per.append({"member": mk.member_index, "seed": mk.cfg.seed, "gaussians": len(mk.g),
                    "model_bytes": gaussians_nbytes(mk.g), "seconds": mk.clock["train"],
                    "psnr": mm.get("psnr"), "ssim": mm.get("ssim")})
    return {"members": len(members), "from": ctx.cfg.ensemble_from if split else "init",
            "shared_stages": [n for n, _ in stages[:split]],
            "seed_stride": MEMBER_SEED_STRIDE, "gaussians": sum(p["gaussians"] for p in per),
            "model_bytes": sum(p["model_bytes"] for p in per), "per_member": per,
            "member_psnr_mean": float(np.mean([p["psnr"] for p in per])),
            "member_stages": [dict(s, member=mk.member_index) for mk in members[1:] for s in mk.stages],
            "note": "the test metrics (mean) are the mean image's; per_member: each model's own images; "
                    "member 0's seconds include the shared stages; `stages` holds member 0's (and the shared) "
                    "stages, member_stages the other members'"}


def main_run(cfg: RunConfig, overwrite: bool = False, quiet: bool = False) -> int:
    """`reings run`: run and print one summary line."""
    m = run(cfg, overwrite=overwrite, quiet=quiet).metrics
    print(f"{m['method']} on {m['data']} ({m['views']} views, {m['device']}): "
          + " ".join(f"{k.upper()} {v:.4f}" for k, v in m["mean"].items())
          + f" | {m['seconds']['method']:.1f} s training ({m['seconds']['total']:.1f} s total)"
          + f" | Gaussians {m['gaussians']}"
          + (f" | ensemble of {e['members']}: {e['gaussians']} Gaussians, members' PSNR "
             + " / ".join(f"{p['psnr']:.4f}" for p in e["per_member"]) if (e := m.get("ensemble")) else "")
          + f" | {cfg.output.out}")
    return 0
# }}}
