"""`fit`: the training engine shared by the baselines (3dgs, dngaussian) and the three ReInGS
optimizations (coarse, fine, final). ONE loop, whatever the device.

One iteration, in DNGaussian's order (docs/method.md §2.4): an optional hard-depth pass (opacity fixed,
gradient to the means only, its own Adam step), an optional soft-depth pass (gradient to the
opacities only, its own step), then the photometric pass (+ regularisers) stepping every group,
the densification statistics and the densify/prune schedule. Adam keeps a step count per group.
With `LossConfig.soft_depth_shared` (speed; off by default) the soft-depth term is taken on the
photometric pass's render instead: its opacity gradient is added into the photometric gradients
after the densification statistics, and one Adam step takes both. With `LossConfig.drop_gamma`
(DropGaussian, docs/method.md §9) the photometric pass's renders leave out a random subset of
the Gaussians (`drop_at`), the kept ones' opacities compensated. With the view_warp term
(`LossConfig.view_warp_weight`, docs/binocular.md §4) the photometric pass renders a virtual view
once, as a kept frame (`Trainer.forward(keep=True)`), and backpropagates it into the same step.

The loop (`_Iteration`) calls only the Trainer contract (reings/backends/base.py); the backend makes
the trainer (`backend.trainer(images, engine=...)`):
    "device"  the state resident on an OpenCL device (reings/backends/opencl/trainer.py): only
              scalars cross the bus, and only on logging iterations; densification reads its
              decision columns and edits the rows on the device; the state comes back for eval,
              checkpoints and the result.
    "host"    numpy state through the backend's render / render_vjp / host losses and the numpy
              twins (reings/backends/host_trainer.py); the only one on device "reference".
Both compute the same iteration (bit for bit on PoCL: tests/test_device_fit.py).

What is left to others: kernels and their host code are the backends'; parameter surgery is
`reings.state` / `reings.densify`; schedules are `reings.optim`; the losses' host forms and the
depth patch draws are `reings.losses`.
"""
from __future__ import annotations

import json
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

# block_mean: [H, W, ...] -> [H // s, W // s, ...] float32, the mean of each s x s block (summed in float64), the
# last rows and columns that do not fill a block dropped (depth_pass_camera's pixels): the pooled depth prior of
# the hard pass at 1/s, the views of a fit at 1/s. One definition with the block_mean stage's float64 twin
from .backends.reference_block_mean import block_mean
from .backends.reference_drop import Drop
from .backends.reference_view_warp import draw_baseline, virtual_camera
from .config import DensifyConfig, TrainConfig, blur_sigmas, check_value, count_at_least_1
from .seeding import IterationDraws
from .types import Camera, Gaussians

SH_C0 = 0.28209479177387814


# {{{ initialisation helpers

def scene_extent(cameras) -> float:
    """DNGaussian/3DGS `cameras_extent`: 1.1 x the largest distance of a training camera centre
    from the centroid of the training centres (getNerfppNorm). 1.0 for a single camera."""
    c = np.array([cam.center for cam in cameras], dtype=np.float64)
    if len(c) < 2:
        return 1.0
    r = np.linalg.norm(c - c.mean(0), axis=1).max()
    return float(1.1 * r) if r > 0 else 1.0


def knn_log_scales(means: np.ndarray, k: int = 3) -> np.ndarray:
    """log(sqrt(mean squared distance to the k nearest neighbours)), per axis (3DGS init)."""
    n = len(means)
    if n < 2:
        return np.full((n, 3), np.log(0.01), np.float32)
    from scipy.spatial import cKDTree

    kk = min(k + 1, n)
    d, _ = cKDTree(means.astype(np.float64)).query(means.astype(np.float64), k=kk)
    d2 = np.mean(np.square(d[:, 1:]), axis=1)
    s = np.sqrt(np.maximum(d2, 1e-14))
    return np.repeat(np.log(s)[:, None], 3, axis=1).astype(np.float32)


def gaussians_from_points(points: np.ndarray, colors: np.ndarray | None, sh_degree: int,
                          rng: np.random.Generator, opacity: float = 0.1) -> Gaussians:
    """3DGS-style initial Gaussians: identity rotation, opacity 0.1, 3-NN scale, SH DC from the
    colours (DNGaussian's near-grey rand/255 when colours are None), higher SH zero."""
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    n = len(pts)
    k = (sh_degree + 1) ** 2
    sh = np.zeros((n, k, 3), np.float32)
    if colors is None:
        sh[:, 0] = rng.random((n, 3)) / 255.0  # DNGaussian random init: colour ~ 0.5 grey
    else:
        sh[:, 0] = (np.asarray(colors, np.float32).reshape(-1, 3) - 0.5) / SH_C0
    quats = np.zeros((n, 4), np.float32)
    quats[:, 0] = 1
    logit = np.log(opacity / (1 - opacity))
    return Gaussians(pts, quats, knn_log_scales(pts), np.full(n, logit, np.float32), sh)


def random_points_in_box(lo, hi, n: int, rng: np.random.Generator) -> np.ndarray:
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return (lo + rng.random((n, 3)) * (hi - lo)).astype(np.float32)
# }}}


@dataclass
class History:
    """What `fit` reports: per-logged-iteration loss, train PSNR and Gaussian count; seconds."""

    iteration: list = field(default_factory=list)
    loss: list = field(default_factory=list)
    train_psnr: list = field(default_factory=list)
    n_gaussians: list = field(default_factory=list)
    seconds: list = field(default_factory=list)  # wall seconds since the start of this fit
    densify: list = field(default_factory=list)  # (iteration, counts) of each densification
    eval: list = field(default_factory=list)  # (iteration, seconds, metrics) from eval_fn
    view_warp: list = field(default_factory=list)  # (iteration, loss, valid fraction) of the view_warp term, when logged
    depth_metric: list = field(default_factory=list)  # (iteration, loss) of the metric depth term, when logged
    # (iteration, loss, valid fraction[, occluded fraction: with its occlusion test on]) of the cross_warp
    # term, when logged (the loss: all its levels, LossConfig.cross_warp_blur; the fractions: the sharp level's)
    cross_warp: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class FitResult:
    gaussians: Gaussians
    history: History
    seconds: float
    state: object = None
    checkpoints: int = 0  # checkpoints this call wrote (a resumed fit counts its own only)
    # the OpenCL programs built on this fit's clock, {"programs", "seconds"} (None: no kernel library);
    # `backend.prepare` builds the fit's programs before the clock starts, so normally none
    kernel_builds: dict | None = None


def _psnr(mse: float) -> float:
    """The train PSNR of a mean squared error (Trainer.read_mse), images in [0, 1]."""
    return float(-10 * np.log10(max(mse, 1e-12)))


def _save_checkpoint(path: str, state, rng, history: History, extra: dict) -> None:
    from .io.files import atomic_write

    arrays = state.to_arrays()
    arrays["rng_state"] = np.frombuffer(json.dumps(rng.bit_generator.state).encode(), np.uint8)
    arrays["history"] = np.frombuffer(json.dumps(history.to_dict()).encode(), np.uint8)
    arrays["extra"] = np.frombuffer(json.dumps(extra).encode(), np.uint8)
    # atomic, through a unique temp file: a crash leaves the previous checkpoint intact, and a
    # symlink planted at a predictable temp name is never written through
    with atomic_write(path, binary=True) as f:
        np.savez(f, **arrays)


def _load_checkpoint(path: str):
    from .state import TrainState

    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        rng_state = json.loads(bytes(d.pop("rng_state")).decode())
        hist = History(**json.loads(bytes(d.pop("history")).decode()))
        extra = json.loads(bytes(d.pop("extra")).decode())
        return TrainState.from_arrays(d), rng_state, hist, extra
    except Exception as e:  # truncated, not an npz, missing or malformed entries
        raise ValueError(f"{path}: unreadable checkpoint ({type(e).__name__}: {e}); delete it to redo this stage, "
                         "or rerun with --overwrite") from None


def warp_baseline(seed: int, it: int, max_baseline: float, draws=None) -> float:
    """The signed baseline of iteration `it`'s virtual view (view_warp): |b| ~ U[0, max), random sign
    (reference_view_warp.draw_baseline), from a generator of its own per iteration
    (numpy.random.default_rng([seed, 1, it])), so the term shifts no other draw and a resumed fit draws
    the same baselines. draws: a reings.seeding.IterationDraws of `seed`, which gives the same two
    doubles without building the generator (the fit's loop passes one)."""
    if draws is None:
        return draw_baseline(np.random.default_rng([seed, 1, it]), max_baseline)
    if draws.seed != seed:
        raise ValueError(f"warp_baseline: draws of seed {draws.seed} for seed {seed}")
    u_mag, u_sign = draws.randoms(1, it, 2)  # draw_baseline's two draws, in its order
    mag = u_mag * float(max_baseline)
    return (1.0 if u_sign < 0.5 else -1.0) * mag


def drop_at(gamma: float, seed: int, it: int, iterations: int, draws=None) -> Drop | None:
    """DropGaussian's mask of iteration `it` (1-based) of a fit of `iterations` (docs/method.md
    §9): drop rate gamma * it / iterations, the key a uint32 of its own per iteration
    (numpy.random.SeedSequence([seed, 2, it])), so the term shifts no other draw, and a resumed fit
    drops the same Gaussians. None when gamma is 0 (off: every render as without the option).
    draws: a reings.seeding.IterationDraws of `seed` (the same key, computed a block at a time)."""
    if not gamma:
        return None
    if draws is None:
        key = int(np.random.SeedSequence([seed, 2, it]).generate_state(1, np.uint32)[0])
    elif draws.seed != seed:
        raise ValueError(f"drop_at: draws of seed {draws.seed} for seed {seed}")
    else:
        key = draws.uint32_key(2, it)
    return Drop.at_rate(gamma * it / iterations, key)


def cross_partner(seed: int, it: int, view: int, n_views: int) -> int:
    """The partner view of iteration `it`'s cross_warp term (docs/method.md §12): uniform over the
    training views other than `view`, from a generator of its own per iteration
    (numpy.random.default_rng([seed, 3, it])), so the term shifts no other draw and a resumed fit
    draws the same partners. n_views >= 2."""
    k = int(np.random.default_rng([seed, 3, it]).integers(n_views - 1))
    return k + (k >= view)


def _view_of(it: int, seed: int, n_views: int) -> int:
    """The training view of iteration `it` (1-based): a fresh permutation of the views per epoch."""
    epoch, pos = divmod(it - 1, n_views)
    return _epoch_order(seed, epoch, n_views)[pos]


@lru_cache(maxsize=8)
def _epoch_order(seed: int, epoch: int, n_views: int) -> tuple:
    """The views of one epoch in order, drawn once per epoch (a generator per iteration costs ~60 us
    of an iteration's host time)."""
    return tuple(int(v) for v in np.random.default_rng([seed, epoch]).permutation(n_views))


class _Bookkeeping:
    """What the loop does around an iteration: the progress bar, history logging, eval probes and
    checkpoints. `sync(params_only)` brings the state to the host first (Trainer.download).
    `clock` (seconds, monotonic) times the checkpoints' floor `checkpoint_seconds` (checkpoint_due)."""

    def __init__(self, cfg, state, history, rng, t0, progress, desc, checkpoint, checkpoint_every,
                 eval_fn, eval_every, log_every, sync=None, checkpoint_seconds: float = 0.0,
                 clock=time.perf_counter, phase=None, rows=None):
        self.cfg, self.state, self.history, self.rng, self.t0 = cfg, state, history, rng, t0
        self.desc, self.checkpoint, self.checkpoint_every = desc, checkpoint, checkpoint_every
        self.checkpoint_seconds, self.clock = checkpoint_seconds, clock
        self.last_checkpoint = clock()  # the fit's (re)start counts as one for the floor
        self.checkpoints = 0  # written by this call of fit
        self.eval_fn, self.eval_every, self.log_every = eval_fn, eval_every, log_every
        self.sync = sync or (lambda params_only: None)
        self.rows = rows or (lambda: len(self.state))  # the trainer's Gaussian count: with the device
        # trainer the host state is current only after a sync, and after a params-only one (the eval
        # probe) its parameters may have more rows than its moments and statistics until the next
        # full download; nothing reads those in between
        self.phase = phase or (lambda name: nullcontext())  # Trainer.phase: "probe", "checkpoint" in a profile
        self.bar = None
        if progress:
            from tqdm import tqdm

            self.bar = tqdm(total=cfg.iterations, initial=state.iteration, desc=desc, leave=False,
                            dynamic_ncols=True)

    def logs(self, it: int) -> bool:
        return it % self.log_every == 0 or it == self.cfg.iterations

    def end(self, it: int, deg: int, loss, psnr) -> None:
        """After iteration `it` (loss and train PSNR are only read on logging iterations)."""
        h, st, last = self.history, self.state, it == self.cfg.iterations
        if self.logs(it):
            h.iteration.append(it)
            h.loss.append(float(loss))
            h.train_psnr.append(psnr)
            h.n_gaussians.append(self.rows())
            h.seconds.append(time.perf_counter() - self.t0)
        if self.eval_fn is not None and self.eval_every and (it % self.eval_every == 0 or last):
            with self.phase("probe"):
                self.sync(True)
                h.eval.append((it, time.perf_counter() - self.t0, self.eval_fn(st.gaussians(deg))))
        if self.checkpoint_due(it):
            with self.phase("checkpoint"):
                self.sync(False)
                _save_checkpoint(self.checkpoint, st, self.rng, h, {"desc": self.desc})
            self.last_checkpoint = self.clock()
            self.checkpoints += 1
        if self.bar is not None:
            self.bar.update(1)
            if it % self.log_every == 0:
                el = time.perf_counter() - self.t0
                self.bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{psnr:.2f}", N=self.rows(),
                                     its=f"{it / max(el, 1e-9):.1f}")

    def checkpoint_due(self, it: int) -> bool:
        """Whether the checkpoint is written after iteration `it`: always after the fit's last
        iteration; at a multiple of `checkpoint_every` when at least `checkpoint_seconds` have passed
        since the last one written (or since the fit started or resumed); 0 s: at every multiple.
        Which iterations write one changes no value of the fit (a download reads, a resume from any
        of them is bit-identical), only how much a kill loses."""
        if not self.checkpoint:
            return False
        if it == self.cfg.iterations:
            return True
        return it % self.checkpoint_every == 0 and self.clock() - self.last_checkpoint >= self.checkpoint_seconds

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _training_views(views) -> tuple[list, list]:
    """(images, cameras) of a Scene or of (image, Camera) pairs, checked."""
    if hasattr(views, "images"):
        images, cameras = list(views.images), list(views.cameras)
    else:
        images, cameras = [v[0] for v in views], [v[1] for v in views]
    if not images:
        raise ValueError("fit: no training views")
    for i, (im, cam) in enumerate(zip(images, cameras)):
        if not isinstance(cam, Camera):
            raise TypeError(f"fit: view {i} has no reings.Camera")
        if np.shape(im) != (cam.height, cam.width, 3):
            raise ValueError(f"fit: view {i} image shape {np.shape(im)} != camera {cam.height}x{cam.width}x3")
    return images, cameras


def _initial_state(init: Gaussians, cfg: TrainConfig, checkpoint: str | None):
    """(TrainState, rng, History): from the checkpoint if it exists, else fresh from `init`."""
    from . import densify as D
    from .state import TrainState

    rng = np.random.default_rng(cfg.seed)
    history = History()
    if checkpoint and os.path.exists(checkpoint):
        state, rng_state, history, _ = _load_checkpoint(checkpoint)
        rng.bit_generator.state = rng_state
    else:
        state = TrainState.from_gaussians(init, cfg.sh_degree)
        D.init_stats(state)
    return state, rng, history


def _depth_weights(targets, confidence, strength: float):
    """Per view the depth loss's per-pixel weights (reference_loss.depth_confidence_weights), or
    None: unweighted when the strength is 0 or no view has a confidence."""
    if not 0.0 <= strength <= 1.0:  # also NaN
        raise ValueError(f"fit: LossConfig.depth_confidence must lie in [0, 1], got {strength}")
    if not strength or confidence is None or all(c is None for c in confidence):
        return None
    if len(confidence) != len(targets):
        raise ValueError(f"fit: {len(confidence)} depth confidences for {len(targets)} depth targets")
    from .backends.reference_loss import depth_confidence_weights

    return [None if c is None or t is None else depth_confidence_weights(c, strength)
            for t, c in zip(targets, confidence)]


def _metric_weights(targets, confidence):
    """Per view the metric depth term's weights: the prior's confidence, or 1 everywhere for a view
    whose prior has none (the exact depths of the procedural scene); None without a target."""
    conf = [None] * len(targets) if confidence is None else list(confidence)
    if len(conf) != len(targets):
        raise ValueError(f"fit: {len(conf)} depth confidences for {len(targets)} depth targets")
    return [None if t is None else (np.ones(np.shape(t), np.float32) if c is None else np.asarray(c, np.float32))
            for t, c in zip(targets, conf)]


def depth_pass_camera(cam, scale: int, option: str = "hard_depth_scale"):
    """The hard depth pass's camera at 1/scale of `cam`'s resolution (LossConfig.hard_depth_scale; the view_warp
    term's virtual camera at LossConfig.view_warp_scale; a fit's views at RunConfig.fit_scale): the intrinsics
    divided by scale, so that its pixel (i, j) covers cam's pixels [s i, s i + s) x [s j, s j + s) (pixel
    centres at +0.5 in both); the last rows and columns that do not fill a block are dropped. `option`: the
    setting a view too small for one block is refused under."""
    from .types import Camera

    if scale == 1:
        return cam
    w, h = cam.width // scale, cam.height // scale
    if w < 1 or h < 1:
        raise ValueError(f"{option} {scale}: a {cam.width}x{cam.height} training view has no {scale}x{scale} block")
    K = cam.K.copy()
    K[:2] /= scale
    return Camera(K, cam.viewmat, w, h)


def _hard_cameras(cameras, depth_targets, L):
    """The hard depth pass's camera per view at LossConfig.hard_depth_scale (`depth_pass_camera`; a view
    without a target keeps its own), or None when the pass runs at the views' resolution."""
    s = L.hard_depth_scale
    if not (L.hard_depth and s > 1 and depth_targets is not None):
        return None
    return [c if t is None else depth_pass_camera(c, s) for c, t in zip(cameras, depth_targets)]


def _depth_uploads(depth_targets, weights, metric, cameras, hard_cams, scale: int):
    """What fit uploads for the depth terms: (targets, shapes, weights, metric weights). With the hard
    pass's own cameras (`_hard_cameras`) its targets (block means of the prior and its weights) follow
    the views' own: view i's at index n + i (`_Iteration.hard_offset`)."""
    shapes = [(c.height, c.width) for c in cameras]
    if hard_cams is None:
        return depth_targets, shapes, weights, metric
    targets = list(depth_targets) + [None if t is None else block_mean(t, scale) for t in depth_targets]
    shapes = shapes + [(c.height, c.width) for c in hard_cams]
    if weights is not None:
        weights = list(weights) + [None if w is None else block_mean(w, scale) for w in weights]
    if metric is not None:
        metric = list(metric) + [None] * len(cameras)  # the metric term reads the views' own targets only
    return targets, shapes, weights, metric


@dataclass(frozen=True)
class FitLead:
    """The first iterations of a fit on other views of the same scenes' cameras (a coarse-to-fine
    resolution schedule: `pipeline.scaled_views`, RunConfig.fit_scale_share): iterations 1..`until` on
    `views` (a `fit` views argument: the training views at another resolution) with `depth_targets`
    and `depth_confidence` at that resolution and the fit's config but `loss` and (unless None)
    `densify` (the settings in the part's pixels); the rest on the fit's own views. Parameters, Adam moments, densification statistics and the rng carry across the switch
    (`Trainer.download` into the state, a new trainer's `upload`)."""
    until: int
    views: object
    loss: object  # a LossConfig
    depth_targets: object = None
    depth_confidence: object = None
    densify: object = None  # a DensifyConfig, or None: the fit's


def fit(views, config: TrainConfig, device: str = "pocl", init: Gaussians | None = None,
        depth_targets=None, progress: bool = False, checkpoint: str | None = None,
        checkpoint_every: int = 250, eval_fn=None, eval_every: int = 0, log_every: int = 10,
        desc: str = "fit", extent: float | None = None, engine: str = "auto", adam: str = "auto",
        profile: dict | None = None, depth_confidence=None, checkpoint_seconds: float = 0.0,
        lead: FitLead | None = None) -> FitResult:
    """Optimise Gaussians on the training views.

    views: a `Scene` holding ONLY the training views (`scene.subset(train)`), or a list of
        (image [H,W,3], Camera) pairs.
    config: a TrainConfig (`reings.config.preset("dngaussian")`, ...).
    init: initial Gaussians (required).
    depth_targets: per view [H,W] depth-like maps (a depth prior), or None (no depth terms).
    depth_confidence: per view None / [H,W] confidence in [0, 1] of the depth targets (the stereo
        prior's), or None; `LossConfig.depth_confidence` says how much it weights the depth loss.
    checkpoint: path of an .npz; if it exists the fit resumes from it (same seed, device and
        engine give the same result as an uninterrupted run); it is rewritten every
        `checkpoint_every` its, once at least `checkpoint_seconds` have passed since the last
        rewrite (or the fit's start; 0: every `checkpoint_every` its), and after the last iteration.
    eval_fn: optional f(gaussians) -> dict, called every `eval_every` iterations (speed vs error).
    engine: which Trainer the device's backend makes (`Backend.trainer`): "device" (parameters,
        gradients, Adam moments, densification statistics and the training images stay on the
        OpenCL device: reings.backends.opencl.trainer), "host" (numpy state through render /
        render_vjp and numpy Adam: reings.backends.host_trainer), or "auto", the backend's default
        ("device" on OpenCL devices, "host" on "reference"). Both compute the same iteration
        (tests/test_device_fit.py).
    adam: where the device trainer runs Adam: "kernel" (kernels/adam.cl), "numpy" (numpy on the
        mapped buffers), "auto" (the kernel on GPUs, the faster one measured on CPU devices).
        The host trainer's Adam is numpy.
    profile: optional dict that receives wall seconds per phase (and, device trainer, device
        milliseconds per kernel stage under "device_ms"); the device trainer then waits for the
        queue around each phase.
    lead: a FitLead (its first iterations on other views, e.g. at 1/2 resolution), or None.
    Returns FitResult(gaussians, history, seconds, state, checkpoints).
    """
    from . import densify as D
    from .backends import get_backend
    from .optim import make_optimizer, sh_degree_at

    images, cameras = _training_views(views)
    if init is None or len(init) == 0:
        raise ValueError("fit: `init` must hold at least one Gaussian")
    cfg = config
    # the fit's parts: (last iteration, images, cameras, depth targets, confidences, config), in order
    parts = [(cfg.iterations, images, cameras, depth_targets, depth_confidence, cfg)]
    if lead is not None:
        if not 0 < lead.until <= cfg.iterations:
            raise ValueError(f"fit: FitLead.until must lie in [1, {cfg.iterations}] (the fit's iterations), "
                             f"got {lead.until}")
        lead_images, lead_cameras = _training_views(lead.views)
        if len(lead_images) != len(images):
            raise ValueError(f"fit: FitLead holds {len(lead_images)} views for the fit's {len(images)}")
        parts.insert(0, (lead.until, lead_images, lead_cameras, lead.depth_targets, lead.depth_confidence,
                         replace(cfg, loss=lead.loss, densify=lead.densify or cfg.densify)))
    for _, ims, cams, targets, confidence, part_cfg in parts:  # every part checked before any iteration
        if targets is not None and len(targets) != len(ims):
            raise ValueError(f"fit: {len(targets)} depth targets for {len(ims)} views")
        if targets is not None and confidence is not None and len(confidence) != len(targets):
            raise ValueError(f"fit: {len(confidence)} depth confidences for {len(targets)} depth targets")
        _check_loss(part_cfg.loss)
        for name in ("off_frame_margin", "near_prune_radius"):
            why = check_value(DensifyConfig.__dataclass_fields__[name], getattr(part_cfg.densify, name))
            if why:
                raise ValueError(f"fit: DensifyConfig.{name} {why}")
        _hard_cameras(cams, targets, part_cfg.loss)  # refuses a view with no hard-pass block
    extent = scene_extent(cameras) if extent is None else extent
    backend = get_backend(device)
    state, rng, history = _initial_state(init, cfg, checkpoint)
    todo = [part for part in parts if state.iteration < part[0]]  # a resumed fit skips the parts it has done
    # the first part's trainer before the clock, as its programs (the device trainer's loss kernels); a later
    # part's is made at its switch, on the clock (its image and state uploads are the schedule's cost)
    made = _part_trainer(backend, *todo[0][1:4], todo[0][5].loss, engine, adam, profile) if todo else None
    opt = make_optimizer(state, cfg.optim, extent)
    if hasattr(backend, "prepare"):  # OpenCL: the programs the fit will use, built before its clock
        from .backends.base import select_engine

        for _, _, _, targets, _, part_cfg in todo:
            backend.prepare(**programs_of(part_cfg, state.max_sh_degree, targets is not None,
                                          select_engine(backend, engine)))
    built = kernel_builds(backend)
    t0 = time.perf_counter() - (history.seconds[-1] if history.seconds else 0.0)
    if state.iteration == 0 and cfg.iterations >= 1 and cfg.densify.clean_views:
        # DNGaussian clean_views: drop the Gaussians no training view sees, before iteration 1
        g = state.gaussians(sh_degree_at(1, cfg.sh_degree, cfg.sh_degree_interval))
        D.clean_views(state, np.stack([backend.project_fwd(g, cam, cfg.near).radii > 0 for cam in cameras]))
    cur = {}  # the running part's trainer, for the bookkeeping's callbacks
    book = _Bookkeeping(cfg, state, history, rng, t0, progress, desc, checkpoint, checkpoint_every,
                        eval_fn, eval_every, log_every,
                        sync=lambda params_only: cur["trainer"].download(state, params_only=params_only),
                        checkpoint_seconds=checkpoint_seconds, phase=lambda name: cur["trainer"].phase(name),
                        rows=lambda: cur["trainer"].n)
    hard_ema = None  # the hard depth loss's average (LossConfig.soft_depth_ema_gate) carries across parts
    try:
        for last, ims, cams, targets, confidence, part_cfg in todo:
            if made is None:
                made = _part_trainer(backend, ims, cams, targets, part_cfg.loss, engine, adam, profile)
            trainer, ims, hard_cams, bg_masks = made
            cur["trainer"], made = trainer, None
            _upload_part(trainer, state, bg_masks, cams, targets, confidence, part_cfg.loss, hard_cams)
            iteration = _Iteration(trainer, part_cfg, state, opt, rng, extent, ims, cams, targets, book, hard_cams)
            iteration.hard_ema = hard_ema
            for it in range(state.iteration + 1, last + 1):
                iteration(it)
            hard_ema = iteration.hard_ema
            trainer.download(state)  # the next part's trainer, or the result, takes the state from here
            trainer.finish()
            iteration = trainer = None  # its buffers go before the next part's trainer is made
            cur.clear()
    finally:
        book.close()
    deg = sh_degree_at(cfg.iterations, cfg.sh_degree, cfg.sh_degree_interval)
    seconds = time.perf_counter() - t0
    return FitResult(state.gaussians(deg), history, seconds, state, book.checkpoints, builds_since(backend, built))


def _check_loss(L) -> None:
    """ValueError naming the first LossConfig field `fit` refuses."""
    if not 0.0 <= L.drop_gamma < 1.0:  # also NaN
        raise ValueError(f"fit: LossConfig.drop_gamma must lie in [0, 1), got {L.drop_gamma}")
    for name in ("depth_metric", "cross_warp", "cross_warp_occlusion"):
        v = getattr(L, name)
        if not (v >= 0 and np.isfinite(v)):  # also NaN
            raise ValueError(f"fit: LossConfig.{name} must be >= 0 and finite, got {v}")
    bad = count_at_least_1(L.view_warp_every)
    if bad:
        raise ValueError(f"fit: LossConfig.view_warp_every {bad}")
    if L.hard_depth_scale not in (1, 2, 4):
        raise ValueError(f"fit: LossConfig.hard_depth_scale must be 1, 2 or 4, got {L.hard_depth_scale!r}")
    if L.view_warp_scale not in (1, 2):
        raise ValueError(f"fit: LossConfig.view_warp_scale must be 1 or 2, got {L.view_warp_scale!r}")
    bad = blur_sigmas(L.cross_warp_blur)  # 0 is the sharp level, always taken
    if bad:
        raise ValueError(f"fit: LossConfig.cross_warp_blur {bad}")


def _part_trainer(backend, images, cameras, depth_targets, L, engine, adam, profile):
    """(trainer, images, hard-pass cameras, background masks) for one part of a fit (`fit`, FitLead): a
    trainer made on the part's images (DTU's dark background zeroed where LossConfig.dark_background, its
    masks then returned, else None); a view with no hard-pass block is refused before any upload.
    `_upload_part` then loads it (L: the part's LossConfig)."""
    bg_masks = None
    if L.dark_background:  # DNGaussian's DTU rule (reings.background): training views only
        from .background import dark_background_mask, zero_background

        bg_masks = [dark_background_mask(im) for im in images]
        images = [zero_background(im, m) for im, m in zip(images, bg_masks)]
    trainer = backend.trainer(images, engine=engine, adam=adam, profile=profile)
    return trainer, images, _hard_cameras(cameras, depth_targets, L), bg_masks


def _upload_part(trainer, state, bg_masks, cameras, depth_targets, depth_confidence, L, hard_cams) -> None:
    """Onto one part's trainer (`_part_trainer`): the state, the background masks, the depth targets, their
    weights and the metric term's."""
    trainer.upload(state)
    if bg_masks is not None:
        trainer.upload_bg_masks(bg_masks)
    if depth_targets is not None and (L.hard_depth or L.soft_depth or L.depth_metric):
        targets, shapes, weights, metric = _depth_uploads(
            depth_targets, _depth_weights(depth_targets, depth_confidence, L.depth_confidence),
            _metric_weights(depth_targets, depth_confidence) if L.depth_metric else None, cameras, hard_cams,
            L.hard_depth_scale)
        trainer.upload_depth_targets(targets, shapes, smooth=L.depth_smooth_weight != 0, weights=weights)
        if metric is not None:
            trainer.upload_depth_metric(metric)


def kernel_builds(backend) -> dict | None:
    """The OpenCL programs the backend's kernel library has built in this process and their wall
    seconds (KernelLibrary.builds / build_seconds); None without a kernel library (reference)."""
    lib = getattr(backend, "lib", None)
    if lib is None or not hasattr(lib, "builds"):
        return None
    return {"programs": int(lib.builds), "seconds": float(lib.build_seconds)}


def builds_since(backend, before: dict | None) -> dict | None:
    """kernel_builds(backend) less `before` (an earlier kernel_builds)."""
    now = kernel_builds(backend)
    if now is None or before is None:
        return now
    return {"programs": now["programs"] - before["programs"], "seconds": now["seconds"] - before["seconds"]}


def programs_of(cfg: TrainConfig, max_sh_degree: int, depth: bool, engine: str = "device") -> dict:
    """The options of `OpenCLBackend.prepare` for a fit of `cfg` (a state of `max_sh_degree`; depth: it
    has depth targets; engine: the resolved trainer, "device" or "host"): every SH coefficient count its
    forwards take (the degrees the schedule passes through, and 1 for the importance forwards of
    DensifyConfig.prune_unseen), the rasterizer variants and the loss kernels its passes use (`_Iteration`;
    the device engine's block mean for the view_warp term at 1/S, the host engine's is numpy).
    The soft depth term on the photometric render (`soft_shared`) takes the second-cotangent backward on
    the device engine's sync-binned frames and an opacity-only backward elsewhere: the backend, which knows
    its binning, prepares the ones it may take. The host engine runs the soft term as its own opacity-only
    pass (HostTrainer.backward ignores v_depth_opacity) and the photometric loss through the backend's
    kernels, which the device trainer builds when it is made."""
    from .optim import sh_degree_at
    from .types import SH_COUNTS

    L = cfg.loss
    lo, hi = (sh_degree_at(it, cfg.sh_degree, cfg.sh_degree_interval) for it in (1, max(cfg.iterations, 1)))
    sh_ks = {SH_COUNTS[min(d, max_sh_degree)] for d in range(lo, hi + 1)}
    if cfg.densify.prune_unseen:
        sh_ks.add(1)
    soft, host = depth and L.soft_depth, engine == "host"
    shared = bool(soft and L.soft_depth_shared)
    return {"sh_ks": sorted(sh_ks), "importance": bool(cfg.densify.prune_unseen),
            "opacity_only": bool((soft and (host or not shared)) or L.dark_background),
            "soft_shared": shared and not host,
            "depth_loss": bool(depth and (L.hard_depth or L.soft_depth or L.depth_metric)),
            "view_warp": bool(L.view_warp_weight), "photometric": host,
            "block_mean": bool(L.view_warp_weight and L.view_warp_scale > 1 and not host)}


class _Iteration:
    """The body of `fit`'s loop: one iteration over the Trainer contract (reings/backends/base.py).

    Random draws, in order, from the fit's rng: the depth patch sizes of the hard pass, then of the
    soft pass (`draw_depth_patches`), then densification's split samples; the view of iteration
    `it` comes from its own generator (`_view_of`), as do the view_warp baseline
    (`warp_baseline`), DropGaussian's mask (`drop_at`) and the cross_warp partner
    (`cross_partner`). Values cross from the trainer only when read:
    the loss terms and the train PSNR's error on logging iterations (`logged`: a few words), the hard depth loss when
    `soft_depth_ema_gate` needs it, the decision columns when densification is due."""

    def __init__(self, trainer, cfg: TrainConfig, state, opt, rng, extent: float, images, cameras,
                 depth_targets, book: _Bookkeeping, hard_cams=None):
        from .losses import photometric_weights
        from .types import PARAM_NAMES

        self.tr, self.cfg, self.L, self.state, self.opt, self.rng = trainer, cfg, cfg.loss, state, opt, rng
        self.extent, self.images, self.cameras, self.targets, self.book = extent, images, cameras, depth_targets, book
        self.bg, self.near = tuple(cfg.background), cfg.near
        self.w_l1, self.w_ssim = photometric_weights(self.L.lambda_dssim, self.L.photometric_form)
        self.reg_on = bool(self.L.shape_pena or self.L.scale_pena or self.L.opa_pena)
        self.read_hard_loss = self.L.soft_depth_ema_gate is not None  # the only reader of the hard depth loss
        self.groups = [k for k in PARAM_NAMES if k in opt.lr]
        # the hard pass's cameras and the offset of its targets (LossConfig.hard_depth_scale: _depth_uploads)
        self.hard_cams = cameras if hard_cams is None else hard_cams
        self.hard_offset = 0 if hard_cams is None else len(cameras)
        self.hard_patch_div = cfg.loss.hard_depth_scale if cfg.loss.hard_depth_patches == "area" else 1
        self.hard_ema = None
        self.k = 1  # active SH coefficients of the current iteration
        # the per-iteration draws of drop_at / warp_baseline, a block of iterations at a time (the same numbers)
        self.draws = IterationDraws(cfg.seed) if IterationDraws.supports(cfg.seed) else None

    def __call__(self, it: int) -> None:
        from .optim import sh_degree_at
        from .types import SH_COUNTS

        L, st = self.L, self.state
        self.opt.update_learning_rate(it)
        deg = sh_degree_at(it, self.cfg.sh_degree, self.cfg.sh_degree_interval)
        self.k = SH_COUNTS[min(deg, st.max_sh_degree)]
        vi = _view_of(it, self.cfg.seed, len(self.images))
        cam = self.cameras[vi]
        has_target = self.targets is not None and self.targets[vi] is not None
        # hard depth: opacity fixed, gradient to the means only (DNGaussian render_for_depth)
        if L.hard_depth and has_target and it >= L.hard_depth_from:
            lh = self.depth_pass(it, self.hard_cams[vi], vi + self.hard_offset, "hard", L.hard_depth_opacity,
                                 ("means",), self.read_hard_loss, self.hard_patch_div)
            if lh is not None:
                self.hard_ema = lh if self.hard_ema is None else 0.9 * self.hard_ema + 0.1 * lh
        # soft depth: real opacities, gradient to the opacities only (render_for_opa)
        gate = L.soft_depth_ema_gate is None or (self.hard_ema is not None and self.hard_ema < L.soft_depth_ema_gate)
        soft = L.soft_depth and has_target and it >= L.soft_depth_from and gate
        if soft and not L.soft_depth_shared:
            self.depth_pass(it, cam, vi, "soft", None, ("opacity_logits",), False)
        if L.dark_background:
            self.bg_pass(cam, vi)
        loss, psnr = self.photometric_pass(it, cam, vi, self.book.logs(it), soft=soft and L.soft_depth_shared)
        st.iteration = it
        self.densify(it)
        self.book.end(it, deg, loss, psnr)

    def depth_pass(self, it: int, cam, vi: int, name: str, opacity, groups: tuple, read: bool, div: int = 1):
        """One depth pass (forward, depth loss, backward of `groups`, Adam step of `groups`: here
        each group is the render field of the same name). Returns the depth loss if `read`. div: the
        patch sizes' divisor (`depth_cotangent`)."""
        tr, ph = self.tr, self.tr.phase
        with ph(f"{name}_render"):
            fr = tr.forward(cam, self.k, self.bg, self.near, opacity)
        vd, loss = self.depth_cotangent(it, fr, vi, read, div)
        with ph(f"{name}_backward"):
            gr = tr.backward(fr, None, vd, opacity, groups)
        with ph("adam"):
            tr.adam_step(self.opt, gr, groups)
        return loss

    def depth_cotangent(self, it: int, fr, vi: int, read: bool, div: int = 1):
        """DNGaussian's depth loss of frame `fr` against view `vi`'s prior, patch sizes drawn from
        the fit's rng (the same draws at any `div`; each size divided by div, rounded up, within [2, the
        frame's size]: the hard pass at 1/div resolution with LossConfig.hard_depth_patches 'area'):
        (dL/d depth handle, the loss if `read` else None)."""
        from .losses import draw_depth_patches
        from .optim import depth_smooth_weight_at

        tr, L = self.tr, self.L
        div *= L.depth_patch_div  # a fit at 1/S resolution (RunConfig.fit_scale): the full-resolution patches' area
        with tr.phase("depth_loss"):
            # at div > 1 the draw is capped at the full-resolution frame's size, then divided, at least 2 (a
            # 1-pixel patch has no spread: both terms would vanish), at most the small frame's size
            pl, pg = draw_depth_patches(self.rng, L.depth_patch_range, fr.height * div, fr.width * div)
            if div > 1:
                pl, pg = (min(max(2, -(-p // div)), fr.height, fr.width) for p in (pl, pg))
            vd = tr.depth_loss(fr, vi, pl, pg, L.depth_margin, L.depth_w_local, L.depth_w_global,
                               depth_smooth_weight_at(L, it))
            return vd, (tr.read_depth_loss() if read else None)

    def bg_pass(self, cam, vi: int) -> None:
        """DNGaussian's DTU background pass: real opacities, mean(alpha^2) over the view's
        background pixels, gradient to the opacities only, their own Adam step."""
        tr, ph = self.tr, self.tr.phase
        with ph("bg_render"):
            fr = tr.forward(cam, self.k, self.bg, self.near)
        with ph("bg_alpha"):
            va = tr.bg_alpha(fr, vi)
        with ph("bg_backward"):
            gr = tr.backward(fr, None, None, None, ("opacity_logits",), v_alpha=va)
        with ph("adam"):
            tr.adam_step(self.opt, gr, ("opacity_logits",))

    def photometric_pass(self, it: int, cam, vi: int, log: bool, soft: bool = False):
        """The photometric pass (+ regularisers, the view_warp term, densification statistics,
        the opacity decay), stepping every group. Returns (loss, train PSNR) on logging
        iterations (`logged`: read after the pass's last enqueue), else (None, None).

        soft (`soft_depth_shared`): the soft depth term on this pass's render; after the
        densification statistics are taken, its backward adds the opacities' gradient into the
        held gradients, so one step takes both. Its cotangent is made before the photometric
        backward, which announces it (`backward(v_depth_opacity=)`): the device engine then makes
        the soft backward's records in the photometric pass (the same bits, one rasterize_bwd fewer).

        The metric depth term (LossConfig.depth_metric, docs/method.md §10): its depth cotangent
        joins the training render's backward (added into the view_warp term's when both run); so
        does the cross-view photometric term's (LossConfig.cross_warp, docs/method.md §12; its
        partner view from `cross_partner`; with blur levels, LossConfig.cross_warp_blur, one call per
        level, sharp first, each of weight cross_warp / levels, into the one cotangent). With its
        occlusion test (LossConfig.cross_warp_occlusion) the partner view is rendered first (no
        backward) and its depth held (`hold_depth`: a copy that survives the training view's
        forward), the same for every level.

        With the view_warp term (docs/binocular.md §4.2): the virtual view (the training camera
        shifted by a drawn baseline along its x axis) is rendered first, as a kept frame
        (`forward(keep=True)`: it survives the training view's forward and backward); the term
        reads its image and the training render's depth; its depth cotangent joins the training
        render's backward (whose screen gradients feed the densification statistics, as the
        authors'); then the kept frame is backpropagated into the held gradients: one Adam step.
        The virtual view is rendered once (until 2026-11-25 it was rendered again before its
        backward: the same bits, one forward more). At LossConfig.view_warp_scale S = 2 it is
        rendered at 1/S (`depth_pass_camera`; its render and backward ~1/4 of the pixels) and the
        term is taken on the S-grid (`Trainer.view_warp(..., scale)`, docs/binocular.md §4.5): its
        colour cotangent is the small frame's, its depth cotangent the full-resolution frame's.

        DropGaussian (LossConfig.drop_gamma; docs/method.md §9): every render of this pass (the
        training view's, the virtual view's, the cross_warp partner's) drops the same Gaussians
        (`drop_at`); the shared soft depth term, taken on this pass's render, sees the dropped
        model too, and the occlusion test compares depths of the one dropped model."""
        tr, L, D, ph = self.tr, self.L, self.cfg.densify, self.tr.phase
        drop = drop_at(L.drop_gamma, self.cfg.seed, it, self.cfg.iterations, self.draws)
        warp = L.view_warp_weight > 0 and it >= L.view_warp_from and (it - L.view_warp_from) % L.view_warp_every == 0
        if warp:  # at view_warp_scale S > 1 the virtual view is rendered at 1/S (the term on the S-grid)
            b = warp_baseline(self.cfg.seed, it, L.view_warp_baseline, self.draws)
            vcam = depth_pass_camera(virtual_camera(cam, b), L.view_warp_scale, "view_warp_scale")
            with ph("warp_render"):
                virt = tr.forward(vcam, self.k, self.bg, self.near, drop=drop, keep=True)
        cross = L.cross_warp > 0 and it >= L.cross_warp_from and len(self.cameras) > 1
        j = cross_partner(self.cfg.seed, it, vi, len(self.cameras)) if cross else None
        held = None
        if cross and L.cross_warp_occlusion > 0:  # the partner's depth for the occlusion test (no backward)
            with ph("cross_warp_render"):
                held = tr.hold_depth(tr.forward(self.cameras[j], self.k, self.bg, self.near, drop=drop))
        with ph("photo_render"):
            fr = tr.forward(cam, self.k, self.bg, self.near, drop=drop)
        with ph("photo_loss"):
            v_rgb = tr.photometric(fr, vi, self.w_l1, self.w_ssim, value=log)  # the loss reduction only when logged
        v_depth = None
        if warp:
            with ph("view_warp"):
                v_virt, v_depth = tr.view_warp(virt, fr, vi, b, L.view_warp_weight * L.view_warp_every,
                                               L.view_warp_smooth, L.view_warp_scale)
        metric = bool(L.depth_metric) and self.targets is not None and self.targets[vi] is not None
        if metric:
            with ph("depth_metric"):
                v_depth = tr.depth_metric(fr, vi, L.depth_metric, into=v_depth)
        if cross:  # the cross-view photometric term (docs/method.md §12): a partner training view
            levels = (0.0, *L.cross_warp_blur)  # sharp, then the blur levels: the term is their mean
            with ph("cross_warp"):
                for sigma in levels:
                    v_depth = tr.cross_warp(fr, vi, j, self.cameras[j], L.cross_warp / len(levels), self.near,
                                            into=v_depth, occlusion=L.cross_warp_occlusion, partner_depth=held,
                                            sigma=sigma)
        vd_soft = None
        if soft:  # the soft term's cotangent first: the photometric backward may make its records (below)
            vd_soft, _ = self.depth_cotangent(it, fr, vi, False)
        with ph("photo_backward"):  # held (soft / warp): written where the later backwards add into;
            # the densification statistics from this backward's screen gradients (stats)
            gr = tr.backward(fr, v_rgb, v_depth, v_depth_opacity=vd_soft, hold=soft or warp, stats=True)
        with ph("regularize"):
            if self.reg_on:  # logging: the penalties' value at the parameters before the step, too
                tr.regularize(gr, L.shape_pena, L.scale_pena, L.opa_pena, value=log)
        if soft:  # the frame's depth is this render's; the statistics above came from the photometric backward
            with ph("soft_backward"):  # on the device engine: the records announced above, reduced
                tr.backward(fr, None, vd_soft, None, ("opacity_logits",), into=gr)
        if warp:
            with ph("warp_backward"):
                tr.backward(virt, v_virt, into=gr)
        if D.opacity_decay is not None and it > D.opacity_decay_from:
            with ph("opacity_decay"):  # after the backward, before the step (Binocular3DGS)
                tr.opacity_decay(D.opacity_decay)
        with ph("adam"):
            tr.adam_step(self.opt, gr, self.groups)
        if not log:
            return None, None
        with ph("log"):
            return self.logged(it, fr, vi, warp, metric, cross)

    def logged(self, it: int, fr, vi: int, warp: bool, metric: bool, cross: bool = False):
        """(loss, train PSNR) of a logging iteration's photometric pass, read once the pass is
        enqueued: the first read waits for the queue once, where reading each term where it is
        made (until 2026-11-25) waited mid-pass and brought the image and two parameter groups to the
        host (a GPU idles while the host waits and then enqueues). Each term's buffers survive the
        rest of the pass (the frame until the next forward; the loss kernels' sums until their next
        call), so the values are those of the same renders and parameters: the photometric loss, the
        view_warp, metric depth and cross_warp terms, the penalties at the parameters before the
        step (`regularize(value=True)`); summed in that order. Also appends the terms' own history."""
        tr, h = self.tr, self.book.history
        psnr = _psnr(tr.read_mse(fr, vi))
        loss = tr.read_loss()
        if warp:
            w = tr.read_view_warp()
            loss += w["loss"]
            h.view_warp.append((it, w["loss"], w["valid_fraction"]))
        if metric:
            lm = tr.read_depth_metric()
            loss += lm
            h.depth_metric.append((it, lm))
        if cross:
            c = tr.read_cross_warp()
            loss += c["loss"]
            occl = (c["occluded_fraction"],) if self.L.cross_warp_occlusion > 0 else ()
            h.cross_warp.append((it, c["loss"], c["valid_fraction"], *occl))
        if self.reg_on:
            loss += tr.read_regularize()
        return loss, psnr

    def densify(self, it: int) -> None:
        """Densify / prune / reset opacities when the schedule says so (reings.densify.densify_rows
        on the trainer: the decisions on the host from the few columns they read, the new rows made
        where the state is: on the device a gather). DensifyConfig.prune_unseen: after the surgery
        (its clones and split children are judged at once) the trainer's Omega_G over the training
        views (`Trainer.importance`, on the held state) marks the Gaussians no training pixel
        blends, which go too."""
        from . import densify as D

        if not any(D.schedule(self.cfg.densify, it)):
            return
        with self.tr.phase("densify"):
            dens = D.densify_rows(self.tr, self.cfg.densify, it, self.extent, self.rng,
                                  importance=lambda: self.tr.importance(self.cameras, self.bg, self.near),
                                  cameras=self.cameras, near=self.near)
        if dens:
            self.book.history.densify.append((it, dens))


def with_iterations(config: TrainConfig, iterations: int) -> TrainConfig:
    """A copy of `config` with its schedule squeezed into `iterations` (densification window,
    position-lr decay, depth-term starts and SH steps scaled proportionally)."""
    f = iterations / max(config.iterations, 1)
    sc = lambda v: None if v is None else max(1, int(round(v * f)))  # noqa: E731
    d, o, L = config.densify, config.optim, config.loss
    return replace(
        config, iterations=iterations,
        sh_degree_interval=sc(config.sh_degree_interval),
        optim=replace(o, position_lr_start=int(round(o.position_lr_start * f)),
                      position_lr_max_steps=sc(o.position_lr_max_steps)),
        loss=replace(L, soft_depth_from=sc(L.soft_depth_from), hard_depth_from=max(1, sc(L.hard_depth_from)),
                     depth_smooth_from=sc(L.depth_smooth_from), view_warp_from=sc(L.view_warp_from),
                     cross_warp_from=sc(L.cross_warp_from)),
        densify=replace(d, densify_from=sc(d.densify_from), densify_until=sc(d.densify_until),
                        densify_interval=max(10, sc(d.densify_interval)),
                        opacity_reset_interval=sc(d.opacity_reset_interval), opacity_decay_from=sc(d.opacity_decay_from),
                        size_prune_from=sc(d.size_prune_from)),
    )
