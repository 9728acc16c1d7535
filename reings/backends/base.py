"""The contracts shared by every backend (reference float64 numpy, OpenCL, later Warp): the render
stages (`Backend`) and one training iteration's operations (`Trainer`).

A render is the stage sequence

    project_fwd -> bin -> rasterize_fwd            (forward)
    rasterize_bwd -> isect_reduce -> project_bwd   (backward, inside the backend)

and each stage has the same name in `kernels/<stage>.cl`, in every backend class, in the float64
reference (`reings.backends.reference`) and in `tests/test_<stage>.py`.  The dataclasses below are
the host-side (numpy) view of what passes between stages; the OpenCL backend keeps the same arrays
on the device and only materialises these views for tests and debugging.

Index spaces (names follow brush's `x_from_y` rule):
  gid    Gaussian index, 0..N-1 (input order)
  rank   position of a *visible* Gaussian in (depth t_z, gid) order, 0..V-1 (the OpenCL backend's
         device frames also rank the Gaussians that only the near plane does not cull, with no
         tile: the visible ones keep their relative order and emit slots; opencl/depth_order.py)
  emit   slot of one (Gaussian, tile) intersection in emit order: ranks in order, each Gaussian's
         tiles row-major (ty outer, tx inner); rank r owns slots [offset_from_rank[r], offset_from_rank[r+1])
  isect  position in the list sorted by (tile, depth, gid); tile t owns [tile_ranges[t,0], tile_ranges[t,1])
  tile   ty * tiles_x + tx, tiles of 16x16 pixels
"""
from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Protocol, Sequence

import numpy as np

from ..types import Camera, Gaussians, RenderOutput

TILE_SIZE = 16
ALPHA_MIN = 1.0 / 255.0  # a pair with alpha below this is skipped (3DGS)
ALPHA_MAX = 0.99  # alpha clamp; no gradient flows through the clamp
T_MIN = 1e-4  # a pixel stops *before* the Gaussian that would make T*(1-alpha) < T_MIN
EPS2D = 0.3  # low-pass dilation added to the 2D covariance diagonal
CLAMP_GUARD = 0.3  # Jacobian guard band, fraction of tan(fov/2) (gsplat)
V_RECORD = 10  # floats per intersection gradient record, see `rasterize_bwd`


def grad_columns(sh_k: int) -> dict:
    """Floats per Gaussian of each raw-field gradient buffer of a device backward (project_bwd's outputs
    [N,3], [N,4], [N,3], [N], [N,sh_k,3]), by field."""
    return {"means": 3, "quats": 4, "log_scales": 3, "opacity_logits": 1, "sh": 3 * sh_k}


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """(tiles_x, tiles_y) for an image."""
    return (width + TILE_SIZE - 1) // TILE_SIZE, (height + TILE_SIZE - 1) // TILE_SIZE


def projected_shape_problem(proj) -> str | None:
    """Why a Projected's arrays are not one row per Gaussian of its fields' widths (means2d [N, 2], conics [N, 3],
    depths [N], radii [N], tile_rect [N, 4], colors [N, 3], opacities [N]), or None. The kernels read N rows of each:
    a shorter array was read past its end."""
    n = np.asarray(proj.means2d).shape[0] if np.ndim(proj.means2d) else -1
    for f, tail in (("means2d", (2,)), ("conics", (3,)), ("depths", ()), ("radii", ()), ("tile_rect", (4,)),
                    ("colors", (3,)), ("opacities", ())):
        shape = np.shape(getattr(proj, f))
        if shape != (n,) + tail:
            return f"Projected.{f}: expected shape {(n,) + tail} (N = {n} rows of means2d), got {shape}"
    return None


def tile_rect_problem(tile_rect, radii, width: int, height: int) -> str | None:
    """Why a projection's tile rects cannot be binned on a width x height image, or None. A visible row's rect
    [tx0, tx1) x [ty0, ty1) (radii > 0) is empty (tx1 == tx0 or ty1 == ty0) or has tx0, ty0 >= 0 and every tile id
    ty * tiles_x + tx inside [0, n_tiles) (project_fwd's rects lie in the grid; an uploaded rect may run past its
    right edge while its ids wrap inside it: tests/test_bin.py::test_bin_sync_free_bound); an inverted rect
    (tx1 < tx0 or ty1 < ty0) never is. The binning kernels would write past their buffers otherwise."""
    tiles_x, tiles_y = tile_grid(width, height)
    r = np.asarray(tile_rect, np.int64).reshape(-1, 4)
    vis = np.asarray(radii).reshape(-1) > 0
    tx0, ty0, tx1, ty1 = r[:, 0], r[:, 1], r[:, 2], r[:, 3]
    inverted = vis & ((tx1 < tx0) | (ty1 < ty0))
    live = vis & (tx1 > tx0) & (ty1 > ty0)
    off = live & ((tx0 < 0) | (ty0 < 0) | ((ty1 - 1) * tiles_x + (tx1 - 1) >= tiles_x * tiles_y))
    for bad, what in ((inverted, "inverted (tx1 < tx0 or ty1 < ty0)"),
                      (off, f"off the {tiles_x} x {tiles_y} tile grid (a negative start or a tile id past it)")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            return (f"tile_rect of {int(bad.sum())} visible row(s) {what}, e.g. row {i}: {r[i].tolist()} "
                    "([tx0, ty0, tx1, ty1], half-open)")
    return None


def bin_problem(proj, width: int, height: int) -> str | None:
    """Why `proj` cannot be binned on a width x height image, or None: its arrays' shapes (projected_shape_problem),
    then its visible rows' tile rects (tile_rect_problem). The binning's one check, on OpenCL and in the reference."""
    return projected_shape_problem(proj) or tile_rect_problem(proj.tile_rect, proj.radii, width, height)


def bins_problem(bins, n: int, width: int, height: int) -> str | None:
    """Why `bins` cannot be rasterized for n Gaussians on a width x height image, or None: the arrays' shapes
    ([V], [V + 1], [K], [K], [n_tiles, 2]), gids in [0, n), offset_from_rank from 0 to K without a step down, emit
    slots in [0, K) and tile ranges 0 <= start <= end <= K. The rasterizer reads and writes at these indices: an
    uploaded Bins outside them crashed the process (a segfault)."""
    tiles_x, tiles_y = tile_grid(width, height)
    arrs = {f: np.asarray(getattr(bins, f)) for f in
            ("gid_from_rank", "offset_from_rank", "gid_from_isect", "emit_from_isect", "tile_ranges")}
    v, k = arrs["gid_from_rank"].size, arrs["gid_from_isect"].size
    shapes = {"gid_from_rank": (v,), "offset_from_rank": (v + 1,), "gid_from_isect": (k,), "emit_from_isect": (k,),
              "tile_ranges": (tiles_x * tiles_y, 2)}
    for f, shape in shapes.items():
        if arrs[f].shape != shape or not np.issubdtype(arrs[f].dtype, np.integer):
            return f"Bins.{f}: expected integers of shape {shape}, got {arrs[f].dtype} {arrs[f].shape}"
    off, tr = arrs["offset_from_rank"].astype(np.int64), arrs["tile_ranges"].astype(np.int64)
    checks = (("gid_from_rank", (arrs["gid_from_rank"] < 0) | (arrs["gid_from_rank"] >= n), f"outside [0, {n})"),
              ("gid_from_isect", (arrs["gid_from_isect"] < 0) | (arrs["gid_from_isect"] >= n), f"outside [0, {n})"),
              ("emit_from_isect", (arrs["emit_from_isect"] < 0) | (arrs["emit_from_isect"] >= k), f"outside [0, {k})"),
              ("offset_from_rank", np.r_[off[0] != 0, np.diff(off) < 0, off[-1] != k],
               f"not a run from 0 to K = {k} without a step down"),
              ("tile_ranges", (tr[:, 0] < 0) | (tr[:, 0] > tr[:, 1]) | (tr[:, 1] > k),
               f"not 0 <= start <= end <= K = {k}"))
    for f, bad, what in checks:
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            c = int(bad.sum())
            return f"Bins.{f}: {c} entr{'y' if c == 1 else 'ies'} {what}, e.g. at {i}"
    return None


@dataclass
class Projected:
    """Output of `project_fwd`, one row per Gaussian (gid). Culled rows have radii == 0 and an
    empty tile_rect (all four zeros); their other fields are zero. The tile_rect is opacity-aware
    (reference.alpha_box_rect): a visible row whose opacity is below ALPHA_MIN also has an empty
    tile_rect (all four zeros) and no intersection, but keeps its radius and other fields."""

    means2d: np.ndarray  # [N, 2] (u, v) pixel coordinates
    conics: np.ndarray  # [N, 3] (A, B, C): power = -0.5*(A dx^2 + C dy^2) - B dx dy
    depths: np.ndarray  # [N] camera-space t_z
    radii: np.ndarray  # [N] int32, 0 = culled
    tile_rect: np.ndarray  # [N, 4] int32 (tx0, ty0, tx1, ty1), half-open, clamped to the grid; the
    #                        3-sigma square's tiles cut to the alpha box's (reference.alpha_box_rect)
    colors: np.ndarray  # [N, 3] SH colour + 0.5, clamped at 0
    opacities: np.ndarray  # [N] effective opacity: sigmoid(logit), or the override constant


@dataclass
class Bins:
    """Output of `bin`: the per-tile depth-ordered Gaussian lists."""

    gid_from_rank: np.ndarray  # [V] int32, visible Gaussians in (depth, gid) order
    offset_from_rank: np.ndarray  # [V + 1] int32, exclusive scan of tiles touched, in rank order
    gid_from_isect: np.ndarray  # [K] int32, sorted by (tile, depth, gid)
    emit_from_isect: np.ndarray  # [K] int32, the emit slot of each sorted intersection
    tile_ranges: np.ndarray  # [T, 2] int32 [start, end) into the sorted list


@dataclass
class RasterOut:
    """Output of `rasterize_fwd` (per pixel)."""

    rgb: np.ndarray  # [H, W, 3]
    depth: np.ndarray  # [H, W]
    alpha: np.ndarray  # [H, W]
    final_T: np.ndarray  # [H, W]
    last: np.ndarray  # [H, W] int32: 1 + position, within its tile's list, of the pixel's last blended Gaussian (0: none)
    importance: np.ndarray | None = None  # [N] sum of alpha*T over blended pixels, if asked


@dataclass
class RasterGrads:
    """Output of `rasterize_bwd` after `isect_reduce`: cotangents of the projected quantities."""

    v_means2d: np.ndarray  # [N, 2]
    v_conics: np.ndarray  # [N, 3]
    v_colors: np.ndarray  # [N, 3]
    v_opacities: np.ndarray  # [N] dL/d(effective opacity)
    v_depths: np.ndarray  # [N] dL/d(t_z) through the depth image



# {{{ the training contract
ENGINES = ("auto", "host", "device")


class Frame(Protocol):
    """One forward pass of a trainer (`Trainer.forward`): an opaque handle on its images and
    intermediates, valid until the trainer's next `forward` (a kept frame, `forward(keep=True)`:
    until the next `forward(keep=True)`). The loop reads only its size."""

    width: int
    height: int


@dataclass
class HeldDepth:
    """`Trainer.hold_depth`: a frame's depth and alpha images (device buffers or host arrays, the
    trainer's) that survive the next `forward`, until the next `hold_depth` (`serial` tells which
    it was): the partner view's render for `cross_warp`'s occlusion test."""

    depth: Any
    alpha: Any
    width: int
    height: int
    serial: int


def check_held_depth(held: HeldDepth | None, cam: Camera, serial: int) -> HeldDepth:
    """`held` if it is the trainer's last `hold_depth` (`serial`) and of `cam`'s size; else
    ValueError (cross_warp's occlusion test reads it as camera `cam`'s render)."""
    if held is None:
        raise ValueError("cross_warp: the occlusion test needs partner_depth (hold_depth of the partner's render)")
    if held.serial != serial:
        raise ValueError("cross_warp: partner_depth is stale (another hold_depth came after it)")
    if (held.width, held.height) != (cam.width, cam.height):
        raise ValueError(f"cross_warp: partner_depth is {held.width}x{held.height}, the partner camera "
                         f"{cam.width}x{cam.height}")
    return held


def check_view_warp_scale(virt, frame, scale) -> int:
    """The view_warp term's scale s as an int, if s is 1 or 2 and the kept virtual frame `virt` is of
    the s-grid of `frame` (frame.width // s x frame.height // s: `Trainer.view_warp`); else ValueError."""
    s = int(scale)
    if s != scale or s not in (1, 2):
        raise ValueError(f"view_warp: scale must be 1 or 2, got {scale!r}")
    want = (frame.width // s, frame.height // s)
    if (virt.width, virt.height) != want or min(want) < 1:
        raise ValueError(f"view_warp: at scale {s} the virtual frame must be {want[0]}x{want[1]} (the "
                         f"{frame.width}x{frame.height} frame's s-grid), got {virt.width}x{virt.height}")
    return s


class Trainer(Protocol):
    """The operations of one training iteration, on a training state held by a backend.

    `reings.train.fit` runs ONE loop over this contract whatever the backend. Per iteration, for
    each pass (hard depth, soft depth, photometric: DNGaussian's order, reings/train.py):

        fr = forward(cam, k, background, near, opacity_override)
        v  = photometric(fr, view, w_l1, w_ssim)          or   depth_loss(fr, view, ...)
        g  = backward(fr, v_rgb, v_depth, opacity_override, grad_fields)
        regularize(g, ...); accumulate(fr)                 (photometric pass only)
        adam_step(opt, g, groups)

    and, when densification is due (reings.densify.densify_rows): `read_columns` of the few
    columns the decisions need, the decisions on the host, `apply_rows` of the new row set (on the
    device a gather: the state does not cross the bus), `reset_opacity`; with
    DensifyConfig.prune_unseen then `importance(cameras, background, near)` (Omega_G of the state
    the trainer holds, over the training cameras) and, when some Gaussians are unseen, another
    `apply_rows`. With
    DropGaussian on (LossConfig.drop_gamma) the photometric pass's forwards (and the view_warp
    term's virtual ones) take the iteration's mask, `forward(..., drop=)`. The view_warp term
    renders its virtual view once, as a kept frame (`forward(..., keep=True)`), which survives
    the training view's forward and backward: `view_warp` reads it, and its own `backward` adds
    into the held gradients (`hold`, `backward(into=)`). Values are
    read only when asked (`read_loss`, `read_mse`, `read_regularize`, `read_depth_loss`, ...), so a
    device implementation moves nothing over the bus in an iteration the loop does not log, and a
    few words in one that it logs (the image and the parameters stay on the device: `read_rgb`,
    `read_params` are for tests and tools).

    Handles: `forward` returns a `Frame`; the loss methods return the cotangent image (a device
    buffer or a host array) that only `backward` consumes; `backward` returns the gradients per
    parameter group, which `regularize` adds into and `adam_step` consumes. A handle is valid until
    the next call of the method that made it (a kept frame, `forward(keep=True)`, until the next
    such call; held gradients, `hold`, until the next `hold`).

    Names: `k` is the number of active SH coefficients (types.SH_COUNTS[degree]); `grad_fields` are
    render fields (types.FIELDS; None = all); `groups` are parameter groups (types.PARAM_NAMES);
    `view` indexes the training images the trainer was made with (`Backend.trainer`).

    Implementations (made by `Backend.trainer`; both compute the same iteration, bit for bit on
    PoCL: tests/test_device_fit.py):
      DeviceTrainer  reings/backends/opencl/trainer.py: parameters, Adam moments, statistics,
                     images and depth targets resident on one OpenCL device; every step a kernel.
      HostTrainer    reings/backends/host_trainer.py: numpy state; the backend's render /
                     render_vjp / host losses, and the numpy twins (reference_state,
                     reference_loss) for the per-Gaussian steps. Any backend, the float64
                     reference included.

    Adding a loss term: its kernel (kernels/) and float64 twin (reference_loss.py), one method here
    (returning a cotangent for `backward`, or adding into the gradients as `regularize` does), that
    method in both trainers, and one call in the loop (reings/train.py, `_Iteration`).
    """

    def upload(self, state: Any) -> None:
        """Take `state` (a reings.state.TrainState: params / adam moments / stats named in
        reings.types) as the trainer's state: at the start and after every host-side edit of its
        rows. Missing densification statistics start at zero. Device: copied to the device;
        host: the state's arrays are used in place."""

    n: int  # the number of Gaussians the trainer holds

    def apply_rows(self, plan: Any, zero_stats: bool = False) -> None:
        """The trainer's rows become the reings.types.RowPlan `plan` of its rows (parameters from
        their source rows and the plan's fresh rows, moments and statistics of the kept rows, zeros
        for new ones; every statistic zero with `zero_stats`): the densification's surgery and the
        prune of unseen Gaussians. Device: a gather of its own buffers (kernels/gather_rows.cl),
        only the indices and the fresh rows uploaded; host: reference_state.apply_rows on the held
        state. The same bits (tests/test_apply_rows.py)."""

    def read_columns(self, params: Sequence[str], stats: Sequence[str] = ()) -> tuple[dict, dict]:
        """(parameters, statistics): name -> host array of the held state's column, for the
        densification's decisions (device: fresh copies; host: the held arrays themselves)."""

    def write_params(self, arrays: dict) -> None:
        """Write host parameter columns (name -> array of the held shape) into the held state
        (DNGaussian's dark-Gaussian rule edits the opacities before the surgery)."""

    def reset_opacity(self, cap_logit: float) -> None:
        """3DGS's opacity reset: logits <- min(logits, cap_logit) (reference_state.opacity_cap_),
        the opacities' Adam moments zeroed."""

    def download(self, state: Any, params_only: bool = False) -> None:
        """Write the trainer's parameters (and, unless `params_only`, the Adam moments and
        statistics) into `state`, as fresh arrays; step counts and the iteration are the host's.
        Before densification, eval, checkpoints and the result. Host: nothing to copy."""

    def upload_depth_targets(self, targets: Sequence, shapes: Sequence[tuple[int, int]],
                             smooth: bool = False, weights: Sequence | None = None) -> None:
        """The training views' depth targets ([H,W] each, or None for a view without one), once
        per fit; `shapes` the views' (H, W), checked (ValueError). smooth: also prepare each view's
        depth_smooth weights (reference_loss.DepthSmoothWeights), which `depth_loss` needs for a
        non-zero w_smooth. weights: None, or per view None / [H,W] per-pixel weights in [0, 1] of
        the depth loss (reference_loss.depth_confidence_weights of the prior's confidence)."""

    def forward(self, cam: Camera, k: int, background: Sequence[float], near: float,
                opacity_override: float | None = None, drop: Any = None, keep: bool = False) -> Frame:
        """Render the held Gaussians with `k` active SH coefficients from `cam` (project / bin /
        rasterize). opacity_override: every Gaussian blends with this opacity (the hard-depth
        pass). drop: None, or DropGaussian's mask of this render (a reings.backends.reference_drop
        .Drop: the Gaussians it drops are culled by the projection, the kept ones' opacities are
        sigmoid(logit) * drop.scale; docs/method.md §9); never with opacity_override (ValueError).
        The frame keeps it: its `backward` is the VJP of that same masked render, the mask held
        fixed. The frame stays valid until the next `forward`; with keep=True (a kept frame: the
        view_warp term's virtual view) until the next `forward` with keep=True, surviving the
        ordinary forwards and backwards in between (the device trainer renders it into the
        backend's second frame slot). Either way a frame's `backward` reads the held parameters
        again: it comes before the next `adam_step`, `opacity_decay` or `upload`."""

    def photometric(self, frame: Frame, view: int, w_l1: float, w_ssim: float, value: bool = True) -> Any:
        """w_l1 * L1 + w_ssim * (1 - SSIM) of the frame's image against training image `view`
        (reference_loss.weighted_photometric_fwd_bwd; kernels/photometric.cl, or kernels/l1.cl
        when w_ssim == 0). Returns dL/d rgb for `backward`; the loss waits for `read_loss`.
        value=False: a step whose loss nobody reads; a trainer may skip the loss's own reduction
        (the device trainer does on the L1 + SSIM path, and its `read_loss` then raises until the next
        pass with value=True; the L1-only path and the host trainer compute the loss anyway)."""

    def read_loss(self) -> float:
        """The loss of the last `photometric` (a read from the device: call it when logging)."""

    def read_rgb(self, frame: Frame) -> np.ndarray:
        """The frame's rendered image, [H,W,3] float32 on the host (tests, tools)."""

    def read_mse(self, frame: Frame, view: int) -> float:
        """mean((rgb - image)^2) of the frame's image against training image `view`, as float64
        (reference_loss.mse; the device reduces it, kernels/mse.cl, and reads H row sums): the
        loop's train PSNR on logging iterations. Valid while the frame is."""

    def depth_loss(self, frame: Frame, view: int, p_local: int, p_global: int, margin: float,
                   w_local: float, w_global: float, w_smooth: float = 0.0) -> Any:
        """DNGaussian's global-local depth loss of the frame's depth against the target of `view`
        (reference_loss.global_local_depth_loss; patch sizes drawn by the loop with
        reings.losses.draw_depth_patches), plus w_smooth times the depth_smooth term
        (reference_loss.depth_smooth_fwd_bwd; needs upload_depth_targets(smooth=True)). Returns
        dL/d depth for `backward`; the loss waits for `read_depth_loss`."""

    def read_depth_loss(self) -> float:
        """The loss of the last `depth_loss` (a read from the device)."""

    def backward(self, frame: Frame, v_rgb: Any = None, v_depth: Any = None,
                 opacity_override: float | None = None, grad_fields: Sequence[str] | None = None,
                 into: Any = None, v_alpha: Any = None, v_depth_opacity: Any = None, hold: bool = False,
                 stats: bool = False) -> Any:
        """The VJP of the frame's render (with the DropGaussian mask its `forward` had, if any)
        for the cotangents v_rgb / v_depth (from the loss methods; None: zero) and the frame's
        `opacity_override`, restricted to `grad_fields` (None: every field). Returns the
        gradients per parameter group (handle for `regularize`, `adam_step`); only the groups of
        `grad_fields` are present. into: gradients from `hold` (the same SH
        count, holding at least the groups of `grad_fields`): this backward's gradients of those
        groups are added into them (reference_state.grad_add; on OpenCL project_bwd's grad_acc) and `into` is
        returned. v_alpha: a cotangent of the alpha image
        (from `bg_alpha`), or None. v_depth_opacity: a depth cotangent (from `depth_loss`) whose
        opacity-only backward of this frame comes next (`backward(frame, None, it, None,
        ("opacity_logits",), into=...)`); an engine may make that backward's records in this one's
        pass (the device engine does, with the same bits: docs/perf_notes.md §13) or ignore it. It
        changes nothing in this call's result. hold (without `into`): return the gradients as `hold`
        would (a handle that survives the next backward, until the next `hold` or backward with hold,
        which reuse it); the device engine writes them there directly, with no copy. stats: also add
        this backward's densification statistics, as `accumulate(frame)` right after it would (a
        photometric backward of every field); the device engine adds them in its projection's
        backward, with no launch of their own."""

    def upload_bg_masks(self, masks: Sequence) -> None:
        """The training views' background masks ([H,W] bool each, or None), once per fit
        (reings.background.dark_background_mask; `bg_alpha` reads them)."""

    def bg_alpha(self, frame: Frame, view: int) -> Any:
        """dL/d alpha of DNGaussian's DTU background term mean(alpha^2) over view `view`'s
        background pixels (reference_loss.bg_alpha_fwd_bwd; kernels/bg_alpha.cl), for
        `backward(v_alpha=...)`."""

    def upload_depth_metric(self, weights: Sequence) -> None:
        """The metric depth term's per-pixel weights of the training views ([H,W] each, or None:
        no term for that view), once per fit, after `upload_depth_targets` (the term reads the
        targets)."""

    def depth_metric(self, frame: Frame, view: int, weight: float, into: Any = None) -> Any:
        """dL/d depth of the metric depth term weight / S * sum c |D - a t| / t of this frame's
        depth D (alpha a held constant) against view `view`'s target t and weights c
        (reference_loss.depth_metric_fwd_bwd; kernels/depth_metric.cl; docs/method.md §10), for
        `backward(v_depth=...)`; added into `into` (another depth cotangent of the same frame, e.g.
        view_warp's) and returned when given. The loss waits for `read_depth_metric`."""

    def read_depth_metric(self) -> float:
        """The loss of the last `depth_metric` (a read from the device; the loss's sums are taken
        now, from that call's frame: valid while the frame is, i.e. until the next `forward`)."""

    def hold_depth(self, frame: Frame) -> HeldDepth:
        """The frame's depth and alpha images as a handle that survives the next `forward`, until
        the next `hold_depth` (a copy on the device): the partner view's render for `cross_warp`'s
        occlusion test, rendered before the training view's own frame."""

    def cross_warp(self, frame: Frame, view: int, partner: int, partner_cam: Camera, weight: float, near: float,
                   into: Any = None, occlusion: float = 0.0, partner_depth: HeldDepth | None = None,
                   sigma: float = 0.0) -> Any:
        """dL/d depth of the cross-view photometric term of this frame (a render of training view
        `view`): its depth reprojects each pixel into training view `partner` (camera
        `partner_cam`), whose training image, sampled there, is compared with view `view`'s
        (weight / 3HW * sum |I_partner(p') - I_view(p)|; reference_cross_warp.cross_warp_fwd_bwd;
        kernels/cross_warp.cl; docs/method.md §12), for `backward(v_depth=...)`; added into `into`
        (another depth cotangent of the same frame) and returned when given. occlusion > 0: the
        occlusion test with that tolerance, against `partner_depth` (`hold_depth` of a render of
        `partner_cam`, held constant); 0: no test. sigma > 0: a blur level (LossConfig.cross_warp_blur;
        docs/method.md §12): both training images replaced by reference_cross_warp.blur_image's
        float32 copies at that sigma (made once per view and sigma, kept by the trainer); 0: the
        images themselves. The loss waits for `read_cross_warp`."""

    def read_cross_warp(self) -> dict:
        """{"loss", "valid_fraction", "occluded_fraction"} of the `cross_warp` calls since the last
        `forward` (a read from the device; the loss's sums are taken now, from those calls' frame and
        held partner depth: valid while the frame is, i.e. until the next `forward`; the fit's loop
        reads on logging iterations before it). loss: the sum of the calls' losses, in their order
        (the levels of the term: sharp, then the blur levels); the fractions: the last call's, which
        are every level's of the same frame, partner and occlusion test (validity depends on the
        depth, alpha, cameras and the partner depth, not on the images), so the sharp level's.
        occluded_fraction: the pixels the occlusion test left out (0 without it), of H W as
        valid_fraction."""

    def hold(self, grads: Any) -> Any:
        """The gradients of the last `backward` as a handle that survives the next `backward` (to
        be passed as its `into`): the photometric pass with view_warp backpropagates two renders
        and steps once."""

    def view_warp(self, virt: Frame, frame: Frame, view: int, baseline: float, weight: float,
                  smooth_weight: float, scale: int = 1) -> tuple[Any, Any]:
        """The binocular view-consistency term (Han et al. 2024; docs/binocular.md): the image of
        the kept frame `virt` (`forward(..., keep=True)` from reference_view_warp.virtual_camera(cam,
        baseline)) warped into training view `view` by this frame's rendered depth, against
        training image `view`; weight * (L1 + smooth_weight * disparity smoothness)
        (reference_view_warp.view_warp_fwd_bwd; kernels/view_warp.cl). Returns (dL/d rgb for the
        virtual frame's `backward`, dL/d depth for this frame's); the loss and the valid fraction
        wait for `read_view_warp`. scale s (1 or 2; LossConfig.view_warp_scale, docs/binocular.md
        §4.5): the term on the s-grid: `virt` rendered at 1/s (train.depth_pass_camera of the
        virtual camera), the frame's depth and the training image block-averaged over s x s
        (reference_block_mean.block_mean_fwd; kernels/block_mean.cl), the focal fx / s; dL/d rgb is
        of `virt`'s size, dL/d depth of this frame's (the adjoint of the depth's pooling,
        block_mean_bwd: v / s^2 on every pixel of a block, 0 on the dropped rows and columns);
        `check_view_warp_scale`. s = 1 is the term at the frame's resolution."""

    def read_view_warp(self) -> dict:
        """{"loss", "valid_fraction"} of the last `view_warp` (a read from the device)."""

    def opacity_decay(self, factor: float) -> None:
        """Every held opacity logit x <- logit(factor * sigmoid(x)), in place, Adam moments
        untouched (Binocular3DGS's opacity decay: reference_state.opacity_decay_;
        kernels/regularize.cl opacity_decay)."""

    def regularize(self, grads: Any, shape_pena: float, scale_pena: float, opa_pena: float,
                   value: bool = False) -> None:
        """Add DNGaussian's shape / scale / opacity penalties' gradients at the held parameters
        into `grads` (reference_loss.regularize_fwd_bwd; kernels/regularize.cl); nothing when every
        weight is 0. value: also take the penalties' value at these parameters for
        `read_regularize` (the loop asks when it logs; kernels/regularize.cl regularize_value)."""

    def read_regularize(self) -> float:
        """The penalties' value (float64; 0 when every weight was 0) of the last
        `regularize(..., value=True)` (a read from the device)."""

    def accumulate(self, frame: Frame) -> None:
        """Add the densification statistics of the frame's last backward (a photometric one, every
        field) to the held statistics: reference_state.densify_accumulate of ndc_grad_norm
        (kernels/densify_accumulate.cl). The fit loop asks `backward(..., stats=True)` instead."""

    def adam_step(self, opt: Any, grads: Any, groups: Iterable[str]) -> None:
        """One Adam step of each parameter group in `groups` with `grads`, using `opt`'s learning
        rates, betas, eps and per-group step counts (a reings.optim.Adam; the counts advance here,
        as Adam.step does, empty groups included): reference_state.adam_update (kernels/adam.cl)."""

    def read_params(self, names: Iterable[str]) -> dict[str, np.ndarray]:
        """The held parameter groups `names` as host float32 arrays (may be the state's own
        arrays on the host: read only)."""

    def importance(self, cameras: Sequence, background: Sequence[float], near: float) -> np.ndarray:
        """Omega_G (ReInGS Eq. 7) of the held state over `cameras`, float64 [N]: per camera and
        Gaussian, alpha*T summed over the pixels where it blends, added in camera order; the same
        bits as reings.rendering.gaussian_importance of the held Gaussians (DensifyConfig.prune_unseen)."""

    def phase(self, name: str) -> AbstractContextManager:
        """A `with` block whose wall seconds are added to profile[name] (a no-op without a
        profile dict); the device trainer finishes its queue around it."""

    def finish(self) -> None:
        """Wait for all queued work; with a profile dict, add the device's per-stage milliseconds
        to profile["device_ms"]."""


def select_engine(backend: "Backend", engine: str) -> str:
    """The trainer `backend.trainer(engine=...)` makes: "auto" -> the backend's default
    (backend.engines[0]); "host" / "device" where the backend offers it; else ValueError."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if engine == "auto":
        return backend.engines[0]
    if engine not in backend.engines:
        raise ValueError(f"the {engine} engine needs an OpenCL device; backend {backend.name!r} offers "
                         f"{backend.engines}")
    return engine
# }}}


def render_importance(backend, gaussians: Gaussians, cameras: Sequence[Camera], background: Sequence[float],
                      near: float) -> np.ndarray:
    """Omega_G (ReInGS Eq. 7) through `backend.render`: per Gaussian, the sum over `cameras` (in order)
    of alpha*T over the pixels where it blends, float64 [N]. The one loop behind
    reings.rendering.gaussian_importance and the host trainer's Trainer.importance."""
    omega = np.zeros(len(gaussians), np.float64)
    for cam in cameras:
        omega += backend.render(gaussians, cam, tuple(float(x) for x in background), float(near),
                                want_importance=True).importance
    return omega


class Backend(Protocol):
    """What the package needs from a device; `reings.backends.get_backend(device)` makes one.

    Render stages (tests, debugging) take and return host numpy; `render` / `render_vjp` are the
    fused path behind `reings.render` / `reings.render_vjp`. The host loss methods are the
    `reings.losses` functions on this device; `trainer` makes the training engine's `Trainer`.
    Capabilities are attributes, never compared device strings: `engines` says which trainers
    the backend can make.
    """

    name: str
    engines: tuple[str, ...]  # trainers `trainer` can make, the default first: ("device", "host") or ("host",)
    last_screen: tuple | None  # after a render_vjp with every field: (v_means2d [N,2] float32, radii [N] int32)
    #                            (culled rows zero) for the densification statistics; None after a restricted one

    def project_fwd(self, gaussians: Gaussians, camera: Camera, near: float = 0.01,
                    opacity_override: float | None = None, drop: Any = None) -> Projected:
        """The projection stage (fit's clean_views reads its radii); drop as in `render`."""

    def render(self, gaussians: Gaussians, camera: Camera, background: Sequence[float] = (0, 0, 0),
               near: float = 0.01, opacity_override: float | None = None,
               want_importance: bool = False, drop: Any = None) -> RenderOutput:
        """project_fwd -> bin -> rasterize_fwd of host Gaussians (reings.render). drop: None or
        DropGaussian's mask (`Trainer.forward`)."""

    def render_frames(self, gaussians: Gaussians, cameras: Sequence[Camera],
                      background: Sequence[float] = (0, 0, 0), near: float = 0.01,
                      depth: bool = False) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
        """(rgb [H,W,3], depth [H,W] or None) of one model from many cameras, one frame at a time
        (a camera path): the same images as `render`, the Gaussians sent to the device once."""

    def render_vjp(self, gaussians: Gaussians, camera: Camera, v_rgb: np.ndarray,
                   v_depth: np.ndarray | None = None, v_alpha: np.ndarray | None = None,
                   background: Sequence[float] = (0, 0, 0), near: float = 0.01,
                   opacity_override: float | None = None,
                   grad_fields: Sequence[str] | None = None, drop: Any = None) -> Gaussians:
        """dL/d(raw field) of the render (with DropGaussian's mask `drop`, held fixed) for the
        cotangent images (reings.render_vjp); sets `last_screen`."""

    def photometric_loss(self, rgb: np.ndarray, gt: np.ndarray, w_l1: float,
                         w_ssim: float) -> tuple[float, np.ndarray]:
        """(w_l1 * L1 + w_ssim * (1 - SSIM), float32 dL/d rgb) of host [H,W,3] images."""

    def depth_loss(self, depth: np.ndarray, target: np.ndarray, p_local: int, p_global: int, margin: float,
                   w_local: float = 0.1, w_global: float = 1.0, smooth=None,
                   weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        """(DNGaussian's depth loss, float32 dL/d depth) of a host [H,W] depth against its target;
        smooth: None or (reference_loss.DepthSmoothWeights, w_smooth) for the depth_smooth term;
        weight: None or [H,W] per-pixel weights (reference_loss.depth_norm_loss_fwd_bwd)."""

    def view_warp(self, virt: np.ndarray, depth: np.ndarray, gt: np.ndarray, fx: float, baseline: float,
                  weight: float, smooth_weight: float) -> tuple[dict, np.ndarray, np.ndarray]:
        """({"loss", "valid_fraction"}, float32 dL/d virt [H,W,3], float32 dL/d depth [H,W]) of the
        view_warp term (reference_view_warp.view_warp_fwd_bwd; kernels/view_warp.cl) on host arrays."""

    def trainer(self, images: Sequence[np.ndarray], engine: str = "auto", adam: str = "auto",
                profile: dict | None = None) -> Trainer:
        """A `Trainer` over the training images [H,W,3] (views indexed as given). engine: "auto"
        (engines[0]), "host" or "device" (`select_engine`); adam: the device trainer's Adam
        location ("auto", "kernel", "numpy"); profile: None or a dict for `Trainer.phase` /
        `finish`."""
