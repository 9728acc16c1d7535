"""`HostTrainer`: the Trainer contract (reings/backends/base.py) with the training state as numpy
arrays on the host, through any backend's host methods:

    forward      backend.render of the state's Gaussians, SH packed at k coefficients
                 (reference_state.sh_pack)
    photometric  backend.photometric_loss                 depth_loss  backend.depth_loss
    backward     backend.render_vjp, split into the parameter groups
    regularize   reference_loss.regularize_fwd_bwd        accumulate  reference_state.densify_accumulate
    adam_step    reference_state.adam_update                          of backend.last_screen

The state is not copied: `upload` takes the TrainState's arrays and every step edits them in place,
so `download` into that same state has nothing to do. On the reference backend every pass is the
float64 reference (`fit(device="reference")`); on an OpenCL backend the render and loss kernels run
in their host forms (arrays up, results back, per call): the twin of the device trainer that the
tests check it against (tests/test_device_fit.py, `fit(engine="host")`).

The backend is called exactly as `reings.render` / `reings.render_vjp` would call it (background
rounded to float32, contiguous float32 cotangents, a zero colour cotangent in the depth passes).
"""
from __future__ import annotations

import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass

import numpy as np

from ..types import ACCUM, FIELDS, PARAM_NAMES, Camera, Gaussians, RenderOutput
from .base import HeldDepth, check_held_depth, check_view_warp_scale, render_importance
from .reference_block_mean import block_mean_bwd_f32, block_mean_f32
from .reference_drop import Drop
from .reference_loss import DepthSmoothWeights, mse, regularize_fwd_bwd
from .reference_state import (HeldRows, adam_update, densify_accumulate, grad_add, ndc_grad_norm, opacity_decay_,
                              sh_pack, zero_stats)

_F32 = np.float32


def _f32(a):
    return None if a is None else np.ascontiguousarray(np.asarray(a, dtype=_F32))


def groups_of(grad_fields) -> tuple[str, ...]:
    """The parameter groups (PARAM_NAMES) of render fields (FIELDS; None: all): "sh" is sh_dc and
    sh_rest, every other field its own group."""
    fields = FIELDS if grad_fields is None else tuple(grad_fields)
    return tuple(k for k in PARAM_NAMES if (k in ("sh_dc", "sh_rest") and "sh" in fields) or k in fields)


@dataclass
class HostFrame:
    """One `HostTrainer.forward`: the Gaussians it rendered (sharing the state's arrays until the
    next Adam step), the camera and settings, and the backend's RenderOutput."""

    cam: Camera
    gaussians: Gaussians
    out: RenderOutput
    background: tuple
    near: float
    width: int
    height: int
    drop: Drop | None = None  # DropGaussian's mask of the render (reference_drop); its backward's too


class HostTrainer(HeldRows):
    """The training state of one fit on the host (module docstring). backend: any Backend;
    images: the training images [H,W,3], used as given; profile: None or a dict of wall seconds
    per `phase`. The row edits of densification (`apply_rows`, `read_columns`, `write_params`,
    `reset_opacity`, `n`) are reference_state.HeldRows' on the held state."""

    def __init__(self, backend, images, profile: dict | None = None):
        self.b = backend
        self.images = list(images)
        self.profile = profile
        self.state = None
        self.targets: list = []  # per view: the depth target as given, or None
        self.smooth: list = []  # per view: DepthSmoothWeights or None
        self._loss = self._depth_loss = self._warp = None
        self._reg_value = None  # the last regularize(value=True)'s penalties (read_regularize)
        self.dm: list = []  # per view: (weights, target, S, valid pixels) of the metric depth term, or None
        self._dm = None  # the last depth_metric call's (residual, weights, target, valid, scale), or None
        self._cw: list = []  # the cross_warp calls' (residuals, valid mask, occluded mask, H, W, scale) since the
        # last forward (one per level), for read_cross_warp
        self._cw_blur: dict = {}  # (view, sigma) -> the blurred training image (cross_warp's blur levels)
        self._vw_images: dict = {}  # (view, s) -> training image `view` pooled over s x s (view_warp at 1/s)
        self._held_depth = 0  # hold_depth calls: a held depth is valid while its count is the last
        self._zeros: dict = {}  # (H, W) -> zero colour cotangent of the depth passes
        self._tmp = np.empty(0, _F32)  # Adam scratch, grown geometrically

    # {{{ state transfer
    def upload(self, state) -> None:
        """Trainer.upload: hold `state`'s arrays (no copy)."""
        if ACCUM not in state.stats:
            state.stats.update(zero_stats(len(state)))
        self.state = state

    def download(self, state, params_only: bool = False) -> None:
        """Trainer.download: nothing to do into the held state; copies into another one."""
        if state is self.state:
            return
        src = self.state
        for k in PARAM_NAMES:
            state.params[k] = src.params[k].copy()
            if not params_only:
                state.adam.exp_avg[k] = src.adam.exp_avg[k].copy()
                state.adam.exp_avg_sq[k] = src.adam.exp_avg_sq[k].copy()
        if not params_only:
            state.stats.update({k: v.copy() for k, v in src.stats.items()})

    def upload_depth_targets(self, targets, shapes, smooth: bool = False, weights=None) -> None:
        """Trainer.upload_depth_targets: the targets (and weights, as float32) are used as given."""
        self.targets, self.smooth, self.dweights = [], [], []
        self.dm = []  # upload_depth_metric's, per view
        weights = [None] * len(targets) if weights is None else list(weights)
        if len(weights) != len(targets):
            raise ValueError(f"{len(weights)} depth weights for {len(targets)} depth targets")
        for i, (t, hw, wt) in enumerate(zip(targets, shapes, weights)):
            if t is not None and np.shape(t) != tuple(hw):
                raise ValueError(f"depth target {i} has shape {np.shape(t)}, its view is {tuple(hw)}")
            if wt is not None and np.shape(wt) != tuple(hw):
                raise ValueError(f"depth weight {i} has shape {np.shape(wt)}, its view is {tuple(hw)}")
            self.targets.append(t)
            self.smooth.append(DepthSmoothWeights(t) if smooth and t is not None else None)
            self.dweights.append(None if wt is None or t is None else np.ascontiguousarray(wt, np.float32))

    def read_params(self, names) -> dict:
        """Trainer.read_params: the state's own arrays (read only)."""
        return {k: self.state.params[k] for k in names}

    def importance(self, cameras, background, near: float) -> np.ndarray:
        """Trainer.importance: Omega_G (ReInGS Eq. 7) of the held state over `cameras`, float64 [N]:
        per camera the backend's render with its importance (alpha*T summed over the pixels where each
        Gaussian blends; colours do not enter, so the SH DC alone is rendered), added in camera order
        (reings.rendering.gaussian_importance)."""
        return render_importance(self.b, self.state.gaussians(0), cameras, background, near)
    # }}}

    # {{{ one pass
    def forward(self, cam: Camera, k: int, background, near: float, opacity_override: float | None = None,
                drop: Drop | None = None, keep: bool = False):
        """Trainer.forward: backend.render of the state's Gaussians at k SH coefficients (drop:
        DropGaussian's mask, kept in the frame for its backward). keep: nothing to do, every frame
        holds its own arrays (its backward, render_vjp, renders again where the backend does not
        reuse its last forward)."""
        p = self.state.params
        kmax = 1 + p["sh_rest"].shape[1]
        if not 1 <= k <= kmax:
            raise ValueError(f"active SH coefficients {k} outside [1, {kmax}]")
        sh = sh_pack(p["sh_dc"], p["sh_rest"], k)  # [N, k, 3]
        g = Gaussians(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], sh)
        bg = tuple(float(x) for x in np.asarray(background, _F32).reshape(3))
        out = self.b.render(g, cam, background=bg, near=float(near), opacity_override=opacity_override, drop=drop)
        self._cw = []  # read_cross_warp sums the levels of one frame: those called after this forward
        return HostFrame(cam, g, out, bg, float(near), cam.width, cam.height, drop)

    def read_rgb(self, fr: HostFrame) -> np.ndarray:
        return fr.out.rgb

    def photometric(self, fr: HostFrame, view: int, w_l1: float, w_ssim: float, value: bool = True) -> np.ndarray:
        """Trainer.photometric: backend.photometric_loss; returns dL/d rgb [H,W,3] (the host computes
        the loss anyway; `value` is the device trainer's switch)."""
        self._loss, v = self.b.photometric_loss(fr.out.rgb, self.images[view], w_l1, w_ssim)
        return v

    def read_loss(self) -> float:
        return self._loss

    def depth_loss(self, fr: HostFrame, view: int, p_local: int, p_global: int, margin: float, w_local: float,
                   w_global: float, w_smooth: float = 0.0) -> np.ndarray:
        """Trainer.depth_loss: backend.depth_loss; returns dL/d depth [H,W]."""
        smooth = None
        if w_smooth:
            if self.smooth[view] is None:
                raise RuntimeError("depth smoothness needs upload_depth_targets(..., smooth=True)")
            smooth = (self.smooth[view], w_smooth)
        self._depth_loss, v = self.b.depth_loss(fr.out.depth, self.targets[view], p_local, p_global, margin,
                                                w_local, w_global, smooth, self.dweights[view])
        return v

    def read_depth_loss(self) -> float:
        return self._depth_loss

    def backward(self, fr: HostFrame, v_rgb=None, v_depth=None, opacity_override: float | None = None,
                 grad_fields=None, into: dict | None = None, v_alpha=None, v_depth_opacity=None,
                 hold: bool = False, stats: bool = False) -> dict:
        """Trainer.backward: backend.render_vjp of the frame's Gaussians; returns {group: gradient}
        for the groups of `grad_fields` (SH gradients of inactive coefficients zero), or adds them
        into `into` (reference_state.grad_add) and returns it. The frame's DropGaussian mask
        applies. v_depth_opacity is ignored (the next backward computes its own pass). hold: the
        result as `hold` returns it (copies). stats: `accumulate(fr)` once the backward is done (every
        field: grad_fields None)."""
        del v_depth_opacity
        if stats and grad_fields is not None:
            raise ValueError("backward: stats=True needs a backward of every field (grad_fields=None)")
        if v_rgb is None:
            key = (fr.height, fr.width)
            if key not in self._zeros:
                self._zeros[key] = np.zeros((fr.height, fr.width, 3), _F32)
            v_rgb = self._zeros[key]
        gf = None if grad_fields is None else tuple(grad_fields)
        vg = self.b.render_vjp(fr.gaussians, fr.cam, _f32(v_rgb), _f32(v_depth), _f32(v_alpha), background=fr.background,
                               near=fr.near, opacity_override=opacity_override, grad_fields=gf, drop=fr.drop)
        n, kmax = len(self.state), 1 + self.state.params["sh_rest"].shape[1]
        if len(vg) != n:
            raise ValueError(f"gradient has {len(vg)} rows, state has {n}")
        out = {"means": vg.means, "quats": vg.quats, "log_scales": vg.log_scales, "opacity_logits": vg.opacity_logits}
        groups = groups_of(gf)
        if "sh_dc" in groups:
            sh = np.zeros((n, kmax, 3), _F32)
            sh[:, : vg.sh.shape[1]] = vg.sh
            out["sh_dc"], out["sh_rest"] = sh[:, :1], sh[:, 1:]
        res = {k: out[k] for k in groups}
        if into is not None and not set(res) <= set(into):
            raise ValueError(f"backward into: held groups {sorted(into)} lack {sorted(set(res) - set(into))}")
        if stats:
            self.accumulate(fr)
        if into is None:
            return self.hold(res) if hold else res
        for k, g in res.items():
            grad_add(into[k], g)
        return into

    def upload_bg_masks(self, masks) -> None:
        """Trainer.upload_bg_masks: kept as bool arrays."""
        self.bg_masks = [None if m is None else np.asarray(m, bool) for m in masks]

    def bg_alpha(self, fr: HostFrame, view: int) -> np.ndarray:
        """Trainer.bg_alpha: scale * alpha on the background, scale = float32(2 / count) as the
        kernel computes it (reference_loss.bg_alpha_fwd_bwd is the float64 form)."""
        m = self.bg_masks[view]
        n = int(m.sum())
        scale = _F32(2.0 / n) if n else _F32(0)
        return np.where(m, scale * np.asarray(fr.out.alpha, _F32), _F32(0)).astype(_F32)

    def upload_depth_metric(self, weights) -> None:
        """Trainer.upload_depth_metric: per view None / float32 weights and S (float64), as the
        device trainer keeps them."""
        from .reference_loss import depth_metric_valid

        if len(weights) != len(self.targets):
            raise ValueError(f"{len(weights)} depth-metric weights for {len(self.targets)} depth targets")
        self.dm = []
        for i, (wt, t) in enumerate(zip(weights, self.targets)):
            if wt is None or t is None:
                self.dm.append(None)
                continue
            wa = np.ascontiguousarray(wt, _F32)
            if wa.shape != np.shape(t):
                raise ValueError(f"depth-metric weight {i} has shape {wa.shape}, its target {np.shape(t)}")
            ta = np.ascontiguousarray(t, _F32)
            ok = depth_metric_valid(ta, wa)
            self.dm.append((wa, ta, float(np.sum(wa.astype(np.float64)[ok])), ok))

    def depth_metric(self, fr: HostFrame, view: int, weight: float, into=None) -> np.ndarray:
        """Trainer.depth_metric: kernels/depth_metric.cl's float32 operations in its order (so the
        bits match the kernel's; reference_loss.depth_metric_fwd_bwd is the float64 form); returns
        dL/d depth [H,W], or `into` with it added."""
        rec = self.dm[view] if view < len(self.dm) else None
        d = np.asarray(fr.out.depth, _F32)
        if rec is None:
            self._dm = None
            return np.zeros_like(d) if into is None else into
        wt, t, s, ok = rec
        scale = _F32(weight / s) if s > 0 else _F32(0)
        a = np.asarray(fr.out.alpha, _F32)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            r = d - a * t
            sg = np.where(r > 0, _F32(1), np.where(r < 0, _F32(-1), _F32(0))).astype(_F32)
            g = np.where(ok, scale * wt * sg / t, _F32(0)).astype(_F32)
        self._dm = (r, wt, t, ok, scale)  # the row terms when read (the frame's arrays are fresh per forward)
        if into is None:
            return g
        into += g
        return into

    def read_depth_metric(self) -> float:
        """Trainer.read_depth_metric: the row sums left to right in float32, as depth_metric_rows,
        then in float64; 0 when the last call had no weights."""
        if self._dm is None:
            return 0.0
        r, wt, t, ok, scale = self._dm
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            rows = np.where(ok & np.isfinite(r), wt * np.abs(r) / t, _F32(0)).astype(_F32)
        acc = np.zeros(rows.shape[0], _F32)
        for x in range(rows.shape[1]):
            acc += rows[:, x]
        return float(scale) * float(np.sum(acc.astype(np.float64)))

    def hold_depth(self, fr: HostFrame) -> HeldDepth:
        """Trainer.hold_depth: float32 copies of the frame's depth and alpha."""
        self._held_depth += 1
        return HeldDepth(np.array(fr.out.depth, _F32), np.array(fr.out.alpha, _F32), fr.width, fr.height,
                         self._held_depth)

    def cross_warp(self, fr: HostFrame, view: int, partner: int, partner_cam: Camera, weight: float, near: float,
                   into=None, occlusion: float = 0.0, partner_depth: HeldDepth | None = None,
                   sigma: float = 0.0) -> np.ndarray:
        """Trainer.cross_warp: kernels/cross_warp.cl's float32 operations in its order
        (reference_cross_warp.cross_warp_f32; the float64 form is cross_warp_fwd_bwd), the
        occlusion test against `partner_depth` when occlusion > 0, both training images blurred
        when sigma > 0 (`_cross_warp_image`); returns dL/d depth [H,W], or `into` with it added.
        The loss's row sums wait for `read_cross_warp` (from the residuals kept here)."""
        from .reference_cross_warp import CROSS_WARP_ALPHA_MIN, cross_warp_args, cross_warp_grad_f32

        h, w = fr.height, fr.width
        hm, e = cross_warp_args(fr.cam, partner_cam)
        scale = _F32(weight / (3.0 * h * w)) if h * w else _F32(0)
        tol = _F32(occlusion)
        pd = check_held_depth(partner_depth, partner_cam, self._held_depth) if tol > 0 else None
        g, r, ok, occ = cross_warp_grad_f32(fr.out.depth, fr.out.alpha, self._cross_warp_image(view, sigma),
                                            self._cross_warp_image(partner, sigma), hm, e, near, CROSS_WARP_ALPHA_MIN,
                                            scale, tol, *((pd.depth, pd.alpha) if pd is not None else (None, None)))
        self._cw.append((r, ok, occ, h, w, scale))
        if into is None:
            return g
        into += g
        return into

    def _cross_warp_image(self, view: int, sigma: float):
        """Training image `view` for cross_warp's level sigma: the image as given at 0, else
        reference_cross_warp.blur_image of it as float32 (the device trainer's gt buffer), made at
        the first call of that (view, sigma) and kept for the fit."""
        from .reference_cross_warp import blur_image

        sigma = float(sigma)
        if sigma == 0:
            return self.images[view]
        img = self._cw_blur.get((view, sigma))
        if img is None:
            img = self._cw_blur[(view, sigma)] = blur_image(np.asarray(self.images[view], _F32), sigma)
        return img

    def read_cross_warp(self) -> dict:
        """Trainer.read_cross_warp: as the device trainer's (per call since the last forward,
        cross_warp_rows_f32's row sums and counts now, then summed in float64; the calls' losses
        added in their order, the fractions of the last call)."""
        from .reference_cross_warp import cross_warp_rows_f32

        if not self._cw:
            raise RuntimeError("read_cross_warp before a cross_warp (since the last forward)")
        loss, out = 0.0, None
        for r, ok, occ, h, w, scale in self._cw:
            if h * w == 0:
                out = {"loss": 0.0, "valid_fraction": 0.0, "occluded_fraction": 0.0}
                continue
            rows, counts, occluded = cross_warp_rows_f32(r, ok, occ)
            out = {"loss": float(scale) * float(np.sum(rows.astype(np.float64))),
                   "valid_fraction": int(np.sum(counts)) / (h * w),
                   "occluded_fraction": int(np.sum(occluded)) / (h * w)}
            loss += out["loss"]
        return {**out, "loss": loss}

    def hold(self, grads: dict) -> dict:
        """Trainer.hold: writable float32 copies (render_vjp's arrays are fresh, but `regularize`
        may have rebound them)."""
        return {k: np.array(v, dtype=_F32) for k, v in grads.items()}

    def view_warp(self, virt: HostFrame, fr: HostFrame, view: int, baseline: float, weight: float,
                  smooth_weight: float, scale: int = 1):
        """Trainer.view_warp: backend.view_warp on the host arrays; returns (dL/d virt, dL/d depth).
        scale s > 1: on the s-grid, the frame's depth and the training image pooled by
        kernels/block_mean.cl's float32 operations (reference_block_mean.block_mean_f32; the image's made
        once per view), focal fx / s, the depth cotangent spread back by block_mean_bwd_f32."""
        s = check_view_warp_scale(virt, fr, scale)
        if s == 1:
            self._warp, v_virt, v_depth = self.b.view_warp(virt.out.rgb, fr.out.depth, self.images[view], fr.cam.fx,
                                                            baseline, weight, smooth_weight)
            return v_virt, v_depth
        gt = self._vw_images.get((view, s))
        if gt is None:
            gt = self._vw_images[(view, s)] = block_mean_f32(self.images[view], s)
        self._warp, v_virt, v_depth = self.b.view_warp(virt.out.rgb, block_mean_f32(fr.out.depth, s), gt,
                                                        fr.cam.fx / s, baseline, weight, smooth_weight)
        return v_virt, block_mean_bwd_f32(v_depth, s, (fr.height, fr.width))

    def read_view_warp(self) -> dict:
        return dict(self._warp)

    def opacity_decay(self, factor: float) -> None:
        """Trainer.opacity_decay: reference_state.opacity_decay_ on the state's logits, in place."""
        opacity_decay_(self.state.params["opacity_logits"], factor)

    def regularize(self, grads: dict, shape_pena: float, scale_pena: float, opa_pena: float,
                   value: bool = False) -> None:
        """Trainer.regularize: reference_loss.regularize_fwd_bwd's gradients added into `grads`
        (value: its value kept for `read_regularize`)."""
        if value:
            self._reg_value = 0.0
        if not (shape_pena or scale_pena or opa_pena):
            return
        v, rg = regularize_fwd_bwd(self.state.params, shape_pena, scale_pena, opa_pena)
        if value:
            self._reg_value = v
        for k, g in rg.items():
            grads[k] = grads[k] + g

    def read_regularize(self) -> float:
        """Trainer.read_regularize: regularize_fwd_bwd's float64 value of the last
        regularize(value=True)."""
        if self._reg_value is None:
            raise RuntimeError("read_regularize before a regularize(..., value=True)")
        return self._reg_value

    def read_mse(self, fr: HostFrame, view: int) -> float:
        """Trainer.read_mse: reference_loss.mse of the frame's image against training image `view`."""
        return mse(fr.out.rgb, self.images[view])

    def accumulate(self, fr: HostFrame) -> None:
        """Trainer.accumulate: the backend's last_screen into the statistics."""
        screen = self.b.last_screen
        if screen is None or len(screen[0]) != len(self.state):
            raise RuntimeError("accumulate needs the screen gradients of a backward with every field")
        v2d, radii = screen
        densify_accumulate(self.state.stats, ndc_grad_norm(v2d, fr.width, fr.height), radii > 0, radii)

    def adam_step(self, opt, grads: dict, groups) -> None:
        """Trainer.adam_step: reference_state.adam_update on the state's arrays, in place."""
        st = self.state
        for name in groups:
            if name not in opt.lr:
                raise KeyError(f"adam_step: {name!r} is not a parameter group ({opt.groups})")
            if grads.get(name) is None:
                raise KeyError(f"adam_step: no gradient for group {name!r}")
            p, m, v = st.params[name], st.adam.exp_avg[name], st.adam.exp_avg_sq[name]
            g = np.asarray(grads[name], _F32)
            if g.shape != p.shape or m.shape != p.shape or v.shape != p.shape:
                raise ValueError(f"adam_step: {name!r} gradient {g.shape} / moments {m.shape} vs parameter {p.shape}")
            t = opt.state.step[name] + 1
            opt.state.step[name] = t
            if p.size == 0:
                continue
            if self._tmp.size < p.size:
                self._tmp = np.empty(max(p.size, int(self._tmp.size * 1.5)), _F32)
            tmp = self._tmp[: p.size].reshape(p.shape)
            adam_update(p, m, v, g, opt.lr[name], t, opt.beta1, opt.beta2, opt.eps, tmp)
    # }}}

    # {{{ profiling
    def phase(self, name: str):
        """Trainer.phase: wall seconds of the block into profile[name] (every call here blocks); without
        profiling a shared no-op context."""
        return nullcontext() if self.profile is None else self._phase(name)

    @contextmanager
    def _phase(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.profile[name] = self.profile.get(name, 0.0) + time.perf_counter() - t

    def finish(self) -> None:
        """Trainer.finish: nothing is queued on the host."""
    # }}}
