"""`fit`: the training engine shared by the baselines (3dgs, dngaussian) and the three ReInGS
optimizations (coarse, fine, final).

One iteration, in DNGaussian's order (METHOD.md §2.4): an optional hard-depth pass (opacity fixed,
gradient to the means only, its own Adam step), an optional soft-depth pass (gradient to the
opacities only, its own step), then the photometric pass (+ regularisers) stepping every group,
densification bookkeeping and the densify/prune schedule. Adam keeps a step count per group.

Two engines compute that same iteration (`fit(engine=...)`): "host" moves numpy Gaussians through
render / render_vjp and steps a numpy Adam; "device" (the default on OpenCL devices) keeps the
parameters, gradients, Adam moments, densification statistics and training images on the device
(reings/backends/opencl/trainer.py: Adam in kernels/adam.cl, penalties and statistics in
kernels/train.cl) and reads the state back only for densification, eval, checkpoints and the result.

What is left to others: the per-pixel work (render, render_vjp, photometric loss kernels) is the
backend's; parameter surgery is `reings.state`; schedules are `reings.optim`.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .config import TrainConfig
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

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class FitResult:
    gaussians: Gaussians
    history: History
    seconds: float
    state: object = None


def _psnr(a, b) -> float:
    mse = float(np.mean(np.square(np.asarray(a, np.float64) - b)))
    return float(-10 * np.log10(max(mse, 1e-12)))


def _save_checkpoint(path: str, state, rng, history: History, extra: dict) -> None:
    tmp = path + ".tmp.npz"
    arrays = state.to_arrays()
    arrays["rng_state"] = np.frombuffer(json.dumps(rng.bit_generator.state).encode(), np.uint8)
    arrays["history"] = np.frombuffer(json.dumps(history.to_dict()).encode(), np.uint8)
    arrays["extra"] = np.frombuffer(json.dumps(extra).encode(), np.uint8)
    np.savez(tmp, **arrays)
    os.replace(tmp, path)  # atomic: a crash leaves the previous checkpoint intact


def _load_checkpoint(path: str):
    from .state import TrainState

    with np.load(path) as z:
        d = {k: z[k] for k in z.files}
    rng_state = json.loads(bytes(d.pop("rng_state")).decode())
    hist = History(**json.loads(bytes(d.pop("history")).decode()))
    extra = json.loads(bytes(d.pop("extra")).decode())
    return TrainState.from_arrays(d), rng_state, hist, extra


ENGINES = ("auto", "host", "device")


def _view_of(it: int, seed: int, n_views: int) -> int:
    """The training view of iteration `it` (1-based): a fresh permutation of the views per epoch."""
    epoch, pos = divmod(it - 1, n_views)
    return int(np.random.default_rng([seed, epoch]).permutation(n_views)[pos])


class _Bookkeeping:
    """What both loops do around an iteration: the progress bar, history logging, eval probes and
    checkpoints. `sync(params_only)` brings the state to the host first (the device engine's
    download; nothing for the host engine)."""

    def __init__(self, cfg, state, history, rng, t0, progress, desc, checkpoint, checkpoint_every,
                 eval_fn, eval_every, log_every, sync=None):
        self.cfg, self.state, self.history, self.rng, self.t0 = cfg, state, history, rng, t0
        self.desc, self.checkpoint, self.checkpoint_every = desc, checkpoint, checkpoint_every
        self.eval_fn, self.eval_every, self.log_every = eval_fn, eval_every, log_every
        self.sync = sync or (lambda params_only: None)
        self.bar = None
        if progress:
            from tqdm import tqdm

            self.bar = tqdm(total=cfg.iterations, initial=state.iteration, desc=desc, leave=False,
                            dynamic_ncols=True)

    def logs(self, it: int) -> bool:
        return it % self.log_every == 0 or it == self.cfg.iterations

    def end(self, it: int, deg: int, loss, rgb, gt) -> None:
        """After iteration `it` (loss and rgb are only read on logging iterations)."""
        h, st, last = self.history, self.state, it == self.cfg.iterations
        if self.logs(it):
            h.iteration.append(it)
            h.loss.append(float(loss))
            h.train_psnr.append(_psnr(rgb, gt))
            h.n_gaussians.append(len(st))
            h.seconds.append(time.perf_counter() - self.t0)
        if self.eval_fn is not None and self.eval_every and (it % self.eval_every == 0 or last):
            self.sync(True)
            h.eval.append((it, time.perf_counter() - self.t0, self.eval_fn(st.gaussians(deg))))
        if self.checkpoint and (it % self.checkpoint_every == 0 or last):
            self.sync(False)
            _save_checkpoint(self.checkpoint, st, self.rng, h, {"desc": self.desc})
        if self.bar is not None:
            self.bar.update(1)
            if it % self.log_every == 0:
                el = time.perf_counter() - self.t0
                self.bar.set_postfix(loss=f"{loss:.4f}", psnr=f"{_psnr(rgb, gt):.2f}", N=len(st),
                                     its=f"{it / max(el, 1e-9):.1f}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class _Phases:
    """profile[name] += wall seconds of a block (host engine: every call is blocking already)."""

    def __init__(self, profile: dict | None):
        self.profile = profile

    def __call__(self, name: str):
        from contextlib import contextmanager

        @contextmanager
        def block():
            t = time.perf_counter()
            try:
                yield
            finally:
                self.profile[name] = self.profile.get(name, 0.0) + time.perf_counter() - t

        if self.profile is None:
            from contextlib import nullcontext

            return nullcontext()
        return block()


def fit(views, config: TrainConfig, device: str = "pocl", init: Gaussians | None = None,
        depth_targets=None, progress: bool = True, checkpoint: str | None = None,
        checkpoint_every: int = 250, eval_fn=None, eval_every: int = 0, log_every: int = 10,
        desc: str = "fit", extent: float | None = None, engine: str = "auto", adam: str = "auto",
        profile: dict | None = None) -> FitResult:
    """Optimise Gaussians on the training views.

    views: a `Scene` holding ONLY the training views (`scene.subset(train)`), or a list of
        (image [H,W,3], Camera) pairs.
    config: a TrainConfig (`reings.config.preset("dngaussian")`, ...).
    init: initial Gaussians (required).
    depth_targets: per view [H,W] depth-like maps (a depth prior), or None (no depth terms).
    checkpoint: path of an .npz; if it exists the fit resumes from it (same seed, device and
        engine give the same result as an uninterrupted run); it is rewritten every
        `checkpoint_every` its.
    eval_fn: optional f(gaussians) -> dict, called every `eval_every` iterations (speed vs error).
    engine: "host" (every pass: numpy Gaussians -> render / render_vjp -> numpy Adam), "device"
        (parameters, gradients, Adam moments, densification statistics and the training images
        stay on the OpenCL device: reings.backends.opencl.trainer), or "auto": "device" on OpenCL
        devices, "host" on device "reference". Both compute the same iteration (tests/test_device_fit.py).
    adam: where the device engine runs Adam: "kernel" (kernels/adam.cl), "numpy" (numpy on the
        mapped buffers), "auto" (the kernel on GPUs, the faster one measured on CPU devices).
        The host engine's Adam is numpy.
    profile: optional dict that receives wall seconds per phase (and, device engine, device
        milliseconds per kernel stage under "device_ms"); the device engine then waits for the
        queue around each phase.
    Returns FitResult(gaussians, history, seconds, state).
    """
    from . import densify as D
    from .backends import get_backend
    from .losses import SmoothWeights, depth_loss, photometric_loss, regularizers
    from .optim import make_optimizer, sh_degree_at
    from .rendering import render, render_vjp
    from .state import TrainState

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
    if init is None or len(init) == 0:
        raise ValueError("fit: `init` must hold at least one Gaussian")
    if depth_targets is not None and len(depth_targets) != len(images):
        raise ValueError(f"fit: {len(depth_targets)} depth targets for {len(images)} views")
    if engine not in ENGINES:
        raise ValueError(f"fit: engine must be one of {ENGINES}, got {engine!r}")
    if engine == "auto":
        engine = "host" if device == "reference" else "device"
    if engine == "device" and device == "reference":
        raise ValueError("fit: the device engine needs an OpenCL device, not 'reference'")

    cfg, L = config, config.loss
    extent = scene_extent(cameras) if extent is None else extent
    backend = get_backend(device)
    bg, near = tuple(cfg.background), cfg.near
    rng = np.random.default_rng(cfg.seed)
    history = History()
    if checkpoint and os.path.exists(checkpoint):
        state, rng_state, history, _ = _load_checkpoint(checkpoint)
        rng.bit_generator.state = rng_state
    else:
        state = TrainState.from_gaussians(init, cfg.sh_degree)
        D.init_stats(state)
    opt = make_optimizer(state, cfg.optim, extent)
    V = len(images)
    t0 = time.perf_counter() - (history.seconds[-1] if history.seconds else 0.0)

    def visibility(g):
        return np.stack([backend.project_fwd(g, cam, near).radii > 0 for cam in cameras])

    if engine == "device":
        return _fit_device(backend, images, cameras, depth_targets, cfg, state, opt, rng, history, t0,
                           visibility, progress, checkpoint, checkpoint_every, eval_fn, eval_every, log_every,
                           desc, extent, adam, profile)

    ph = _Phases(profile)
    book = _Bookkeeping(cfg, state, history, rng, t0, progress, desc, checkpoint, checkpoint_every,
                        eval_fn, eval_every, log_every)
    hard_ema = None
    zeros_rgb = {}
    smooth_views = {}  # view -> SmoothWeights, built on first use

    def smooth_of(vi, it):
        """(SmoothWeights, weight) of the depth smoothness at iteration `it`, or None."""
        w = smooth_weight_at(L, it)
        if not w:
            return None
        if vi not in smooth_views:
            smooth_views[vi] = SmoothWeights(depth_targets[vi])
        return smooth_views[vi], w
    try:
        for it in range(state.iteration + 1, cfg.iterations + 1):
            opt.update_learning_rate(it)
            deg = sh_degree_at(it, cfg.sh_degree, cfg.sh_degree_interval)
            vi = _view_of(it, cfg.seed, V)
            cam, gt = cameras[vi], images[vi]
            target = None if depth_targets is None else depth_targets[vi]
            if it == 1 and cfg.densify.clean_views:
                D.clean_views(state, visibility(state.gaussians(deg)))
            key = (cam.height, cam.width)
            if key not in zeros_rgb:
                zeros_rgb[key] = np.zeros((cam.height, cam.width, 3), np.float32)

            # hard depth: opacity fixed, gradient to the means only (DNGaussian render_for_depth)
            if L.hard_depth and target is not None and it >= L.hard_depth_from:
                g = state.gaussians(deg)
                o = L.hard_depth_opacity
                with ph("hard_render"):
                    out = render(g, cam, device, bg, near, opacity_override=o)
                with ph("depth_loss"):
                    lh, vd = depth_loss(out.depth, target, rng, L.depth_patch_range, L.depth_margin,
                                        L.depth_w_local, L.depth_w_global, device, smooth_of(vi, it))
                hard_ema = lh if hard_ema is None else 0.9 * hard_ema + 0.1 * lh
                with ph("hard_backward"):
                    vg = render_vjp(g, cam, zeros_rgb[key], vd, None, device, bg, near, opacity_override=o,
                                    grad_fields=("means",))
                with ph("adam"):
                    opt.step(state.grads(vg, ("means",)))
            # soft depth: real opacities, gradient to the opacities only (render_for_opa)
            gate = L.soft_depth_ema_gate is None or (hard_ema is not None and hard_ema < L.soft_depth_ema_gate)
            if L.soft_depth and target is not None and it >= L.soft_depth_from and gate:
                g = state.gaussians(deg)
                with ph("soft_render"):
                    out = render(g, cam, device, bg, near)
                with ph("depth_loss"):
                    ls, vd = depth_loss(out.depth, target, rng, L.depth_patch_range, L.depth_margin,
                                        L.depth_w_local, L.depth_w_global, device, smooth_of(vi, it))
                with ph("soft_backward"):
                    vg = render_vjp(g, cam, zeros_rgb[key], vd, None, device, bg, near,
                                    grad_fields=("opacity_logits",))
                with ph("adam"):
                    opt.step(state.grads(vg, ("opacity_logits",)))

            # photometric pass (+ regularisers): every group
            g = state.gaussians(deg)
            with ph("photo_render"):
                out = render(g, cam, device, bg, near)
            with ph("photo_loss"):
                loss, v_rgb = photometric_loss(out.rgb, gt, L.lambda_dssim, L.photometric_form, device)
            with ph("photo_backward"):
                vg = render_vjp(g, cam, v_rgb, None, None, device, bg, near)
            grads = state.grads(vg)
            with ph("regularizers"):
                if L.shape_pena or L.scale_pena or L.opa_pena:
                    lr_, rg = regularizers(state.params, L.shape_pena, L.scale_pena, L.opa_pena)
                    loss += lr_
                    for k, v in rg.items():
                        grads[k] = grads[k] + v
            with ph("stats"):
                screen = getattr(backend, "last_screen", None)
                if screen is not None and len(screen[0]) == len(state):
                    v2d, radii = screen
                    D.accumulate(state, D.ndc_grad_norm(v2d, cam.width, cam.height), radii > 0, radii)
            with ph("adam"):
                opt.step(grads)
            state.iteration = it
            with ph("densify"):
                dens = D.maybe_densify(state, cfg.densify, it, extent, rng)
            if dens:
                history.densify.append((it, dens))
            book.end(it, deg, loss, out.rgb, gt)
    finally:
        book.close()
    deg = sh_degree_at(cfg.iterations, cfg.sh_degree, cfg.sh_degree_interval)
    return FitResult(state.gaussians(deg), history, time.perf_counter() - t0, state)


def _fit_device(backend, images, cameras, depth_targets, cfg, state, opt, rng, history, t0, visibility,
                progress, checkpoint, checkpoint_every, eval_fn, eval_every, log_every, desc, extent, adam,
                profile) -> FitResult:
    """`fit`'s loop with the training state on the OpenCL device (reings.backends.opencl.trainer):
    the same iteration as the host loop above, pass for pass and in the same order of random
    draws; only scalars cross the bus (the loss and train PSNR on logging iterations; the hard
    depth loss every iteration only when `soft_depth_ema_gate` needs it): the depth passes run
    kernels/depth_loss.cl on the rendered depth buffer against the depth targets uploaded once per
    fit. The state comes back to the host for densification, eval, checkpoints and the result."""
    from . import densify as D
    from .backends.opencl.trainer import DeviceTrainer
    from .backends.reference_loss import photometric_weights
    from .losses import draw_depth_patches, regularizers
    from .optim import sh_degree_at
    from .state import PARAM_NAMES
    from .types import SH_COUNTS

    L = cfg.loss
    bg, near = tuple(cfg.background), cfg.near
    V = len(images)
    w_l1, w_ssim = photometric_weights(L.lambda_dssim, L.photometric_form)
    reg_on = bool(L.shape_pena or L.scale_pena or L.opa_pena)
    if state.iteration == 0 and cfg.iterations >= 1 and cfg.densify.clean_views:
        # the host loop does this at iteration 1 before anything else; nothing differs before it
        D.clean_views(state, visibility(state.gaussians(sh_degree_at(1, cfg.sh_degree, cfg.sh_degree_interval))))
    dev = DeviceTrainer(backend, images, adam=adam, profile=profile)
    dev.upload(state)
    if depth_targets is not None and (L.hard_depth or L.soft_depth):
        dev.upload_depth_targets(depth_targets, [(c.height, c.width) for c in cameras],
                                 smooth=L.depth_smooth_weight != 0)
    need_hard_loss = L.soft_depth_ema_gate is not None  # the only reader of the hard depth loss
    ph = dev.phase
    groups = [k for k in PARAM_NAMES if k in opt.lr]

    book = _Bookkeeping(cfg, state, history, rng, t0, progress, desc, checkpoint, checkpoint_every,
                        eval_fn, eval_every, log_every,
                        sync=lambda params_only: dev.download(state, params_only=params_only))
    hard_ema = None
    loss = rgb = None
    try:
        for it in range(state.iteration + 1, cfg.iterations + 1):
            opt.update_learning_rate(it)
            deg = sh_degree_at(it, cfg.sh_degree, cfg.sh_degree_interval)
            k = SH_COUNTS[min(deg, state.max_sh_degree)]
            vi = _view_of(it, cfg.seed, V)
            cam, gt = cameras[vi], images[vi]
            target = None if depth_targets is None else depth_targets[vi]

            # hard depth: opacity fixed, gradient to the means only
            if L.hard_depth and target is not None and it >= L.hard_depth_from:
                o = L.hard_depth_opacity
                with ph("hard_render"):
                    fr = dev.forward(cam, k, bg, near, o)
                with ph("depth_loss"):
                    pl, pg = draw_depth_patches(rng, L.depth_patch_range, fr.height, fr.width)
                    vd = dev.depth_loss(fr, vi, pl, pg, L.depth_margin, L.depth_w_local, L.depth_w_global,
                                        smooth_weight_at(L, it))
                    if need_hard_loss:
                        lh = dev.read_depth_loss()
                        hard_ema = lh if hard_ema is None else 0.9 * hard_ema + 0.1 * lh
                with ph("hard_backward"):
                    gr = dev.backward(fr, None, vd, o, ("means",))
                with ph("adam"):
                    dev.adam_step(opt, gr, ("means",))
            # soft depth: real opacities, gradient to the opacities only
            gate = L.soft_depth_ema_gate is None or (hard_ema is not None and hard_ema < L.soft_depth_ema_gate)
            if L.soft_depth and target is not None and it >= L.soft_depth_from and gate:
                with ph("soft_render"):
                    fr = dev.forward(cam, k, bg, near)
                with ph("depth_loss"):
                    pl, pg = draw_depth_patches(rng, L.depth_patch_range, fr.height, fr.width)
                    vd = dev.depth_loss(fr, vi, pl, pg, L.depth_margin, L.depth_w_local, L.depth_w_global,
                                        smooth_weight_at(L, it))
                with ph("soft_backward"):
                    gr = dev.backward(fr, None, vd, None, ("opacity_logits",))
                with ph("adam"):
                    dev.adam_step(opt, gr, ("opacity_logits",))

            # photometric pass (+ regularisers): every group
            log_it = book.logs(it)
            with ph("photo_render"):
                fr = dev.forward(cam, k, bg, near)
            with ph("photo_loss"):
                v_rgb = dev.photometric(fr, vi, w_l1, w_ssim)
                if log_it:
                    loss, rgb = dev.read_loss(), dev.read_rgb(fr)
            with ph("photo_backward"):
                gr = dev.backward(fr, v_rgb)
            with ph("regularizers"):
                if reg_on:
                    if log_it:  # the penalties' value (host, float64) at the parameters before the step
                        loss += regularizers(dev.read_params(("log_scales", "opacity_logits")),
                                             L.shape_pena, L.scale_pena, L.opa_pena)[0]
                    dev.regularize(gr, L.shape_pena, L.scale_pena, L.opa_pena)
            with ph("stats"):
                dev.accumulate(fr)
            with ph("adam"):
                dev.adam_step(opt, gr, groups)
            state.iteration = it
            dens = None
            if any(D.schedule(cfg.densify, it)):
                with ph("densify"):
                    dev.download(state)
                    dens = D.maybe_densify(state, cfg.densify, it, extent, rng)
                    dev.upload(state)
            if dens:
                history.densify.append((it, dens))
            book.end(it, deg, loss, rgb, gt)
    finally:
        book.close()
    dev.download(state)
    dev.finish()
    deg = sh_degree_at(cfg.iterations, cfg.sh_degree, cfg.sh_degree_interval)
    return FitResult(state.gaussians(deg), history, time.perf_counter() - t0, state)


def smooth_weight_at(loss_config, it: int) -> float:
    """The depth smoothness weight at iteration `it` (0 before depth_smooth_from), one rule for
    both engines."""
    L = loss_config
    return float(L.depth_smooth_weight) if L.depth_smooth_weight and it >= L.depth_smooth_from else 0.0


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
                     depth_smooth_from=sc(L.depth_smooth_from)),
        densify=replace(d, densify_from=sc(d.densify_from), densify_until=sc(d.densify_until),
                        densify_interval=max(10, sc(d.densify_interval)),
                        opacity_reset_interval=sc(d.opacity_reset_interval),
                        size_prune_from=sc(d.size_prune_from)),
    )
