"""`DeviceTrainer`: the Trainer contract (reings/backends/base.py) with the training state of one
`reings.fit` resident on one OpenCL device. Made by `OpenCLBackend.trainer` (engine "device").

Kept on the device for the whole fit (buffers of a private `Scratch`, grown geometrically):

    p_<name>, m_<name>, v_<name>   parameters and Adam moments, name in reings.types.PARAM_NAMES,
                                   same layouts as TrainState (sh_rest holds all kmax-1 rows)
    grad2d_accum, grad2d_count, max_radii2d   the densification statistics (reings.types ACCUM,
                                   COUNT, RADII)
    gt<i>                          the training images [H,W,3]
    gt<i>_blur<sigma>              their blurred copies (reference_cross_warp.blur_image), uploaded once per
                                   (view, sigma) at the first cross_warp of that level (LossConfig.cross_warp_blur)
    dt<i>                          the training views' depth targets [H,W] (upload_depth_targets, once per fit)
    dw<i>                          their per-pixel depth-loss weights [H,W] (--depth-confidence; only when given)
    v_rgb, v_depth                 the cotangent images of the current pass
    held_depth, held_alpha         a render's depth and alpha kept past the next forward (hold_depth: the
                                   cross_warp partner's, for its occlusion test)

One pass is `forward` (project / bin / sort / rasterize on the parameter buffers, nothing
uploaded: backend.forward_device) -> a loss (`photometric`: kernels/photometric.cl or l1.cl writing
v_rgb; or `depth_loss`: kernels/depth_loss.cl on the rendered depth buffer and the resident target,
the depth_smooth term fused in, writing v_depth) -> `backward` (backend.backward_device into the
backend's gradient buffers) -> `regularize` (kernels/regularize.cl, added into those buffers) ->
`accumulate` (kernels/densify_accumulate.cl) -> `adam_step` (kernels/adam.cl, every group of the
call in one adam_step_multi launch, or numpy on the mapped buffers: the `adam` location). The host
keeps what is scalar: learning rates and schedules, the per-group step counts (TrainState.adam.step,
so checkpoints carry them), N. The
loss kernels' host code is reings/backends/opencl/losses.py (the backend's `photometric_kernels`,
`depth_loss_kernels`); the per-Gaussian kernels go through the backend's `kernel` / `launch`.

`step_l1` is the plain step of gsplat's benchmark (bench/peer_gsplat.py, bench/peer_step.py): forward,
w_l1 * mean|rgb - gt| by kernels/l1.cl (the `photometric` pass with w_ssim == 0: no SSIM kernel runs),
backward, Adam over all groups; the binning's (V, K) is its only host read (a blocking one in the
sync binning, none sync-free: backend.py, "Binning").

Host overhead per step (bench/peer_step.py --overhead): every launch goes through pyopencl's typed
invoker (program.typed_invoker: the generic one costs ~6.5 us per numpy scalar argument), buffers
are looked up once per upload (`buf`), the camera record buffer is cached per camera (backend), and
nothing is allocated or uploaded per step.

The state goes back to the host (`download`) for checkpoints, eval and the result. Densification
reads only its decision columns (`read_columns`) and edits the rows on the device (`apply_rows`:
kernels/gather_rows.cl on a reings.types.RowPlan); `upload` is for the start and a checkpoint restore.

Shared depth orders (docs/perf_notes.md §9; backend.py, "Depth orders"): every forward passes the
backend an order key (geometry version, the camera's viewmat row 2 as float32 bytes, near as
float32), so forwards of an iteration that see the same camera-space z (the soft depth pass after
an opacity step, the virtual view, the photometric pass) share one depth sort. The geometry version
is drawn from a process-wide counter (unique across trainers sharing a backend) at every write of
the means buffer: `upload` (init, checkpoint restore), `apply_rows` (densification), `write_params`
of "means" and `adam_step` of a "means" group; code that writes p_means otherwise must call
`means_written`.

Adam location (`adam=`): "kernel" (adam.cl, all state on the device), "numpy"
(reference_state.adam_update on buffers mapped into host memory: zero-copy on CPU devices, where buffers are
ALLOC_HOST_PTR), or "auto": the kernel on GPUs, `CPU_DEFAULT_ADAM` on CPU devices (measured on PoCL,
see the constant).

Not here: the loop and schedules (reings/train.py), the loss kernels' host code (losses.py), kernel
math (kernels/).
"""
from __future__ import annotations

import functools
import itertools
import math
import time
from contextlib import ExitStack, contextmanager, nullcontext

import numpy as np

from ...types import ACCUM, COUNT, PARAM_NAMES, RADII
from ..base import HeldDepth, check_held_depth, check_view_warp_scale, grad_columns
from ..reference_cross_warp import CROSS_WARP_ALPHA_MIN, blur_image, cross_warp_args
from ..reference_loss import REG_VALUE_COLS, DepthSmoothWeights, regularize_value
from ..reference_state import adam_update, opacity_cap_, zero_stats
from .program import typed_invoker
from .scratch import Scratch

# Adam location on CPU devices, measured (`python bench/bench_fit.py --device pocl --adam-only`, PoCL
# 3.1 on 2 Zen 5 cores shared with other jobs, so +-30%), ms per step of all six groups:
#     N=20k SH0: kernel 0.60, numpy on mapped buffers 1.88;  N=20k SH3: kernel 4.3, numpy 4.9;
#     N=100k SH3: kernel 21.4, numpy 24.5.
# (Before the padded 2-D range of the strided adam_step the kernel lost at SH3: 6.2 vs 4.6 ms.)
CPU_DEFAULT_ADAM = "kernel"
# the strided adam_step's work-group rows on CPU devices: a group's columns padded to a multiple of this. 16 left 13
# of 16 lanes idle for sh_dc (3 columns) and 7 for SH degree 1's sh_rest (9); 4 gives PoCL 4-lane vectors along a
# row: 0.45 of 16's time for the two SH groups at degree 1 on 2 AVX2 cores (Zen 3), the same bytes
# (bench/results/pocl_epyc_2core_session47/adam_pad_ab.py; docs/perf_notes.md §44)
ADAM_CPU_PAD = 4
# kernels/adam.cl adam_step_multi: group slots of one launch, lanes per line (a strided group's
# columns padded to a multiple of it: PoCL vectorizes along them)
ADAM_SLOTS, ADAM_LX = 6, 16
_ADAM_SLOT_ARGS = 14  # adam_step_multi's arguments per slot (kernels/adam.cl ADAM_SLOT_ARGS): 4 buffers, 8 uint, 2 scalars
ADAM_LOCATIONS = ("auto", "kernel", "numpy")
REG_VALUE_CHUNK = 256  # Gaussians per work-item of regularize_value (its sums are per chunk)
# Gaussians per work-item of regularize_opacity_count (integer counts: any chunk gives the same
# result). 256 kept a CPU's cores busy with few items; on a GPU it left ~200 work-items of 256
# serial exps each, 0.058 ms per step on an H100 (bench/kernel_census.py, docs/perf_notes.md §11)
REG_COUNT_CHUNK_CPU, REG_COUNT_CHUNK_GPU = 256, 8
# regularize_grads' Gaussians per work-item on CPUs (REG_VW, kernels/regularize.cl): the exp calls on 8 lanes
# (docs/perf_notes.md §31); GPUs 1
REG_VW_CPU = 8
_GEOMETRY = itertools.count(1)  # geometry versions, unique in the process (module docstring)
_F32, _F64, _I32, _U32 = np.float32, np.float64, np.int32, np.uint32


_NO_PHASE = nullcontext()  # DeviceTrainer.phase without profiling


def _shape(name: str, n: int, kmax: int) -> tuple:
    return {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,),
            "sh_dc": (n, 1, 3), "sh_rest": (n, kmax - 1, 3)}[name]


def _columns(kmax: int) -> dict:
    """Floats per row of each parameter group (prod of _shape(name, 1, kmax)[1:])."""
    return {"means": 3, "quats": 4, "log_scales": 3, "opacity_logits": 1, "sh_dc": 3, "sh_rest": 3 * (kmax - 1)}


@functools.lru_cache(maxsize=16, typed=True)  # typed: a numpy beta keeps its own arithmetic
def _adam_constants(b1: float, b2: float, eps: float) -> tuple:
    return _F32(b1), _F32(1.0 - b1), _F32(b2), _F32(1.0 - b2), _F32(eps)


def adam_scalars(lr: float, t: int, b1: float, b2: float, eps: float, fp64: bool) -> tuple:
    """The adam_step scalar arguments for step count t, rounded as numpy rounds them in
    `adam_update` (Python floats become float32 operands; 1/sqrt(bc2) is a float64 scalar: math.sqrt
    and np.sqrt are both the correctly rounded square root). The optimizer's constants are made once."""
    bc1 = 1.0 - b1 ** t
    bc2 = 1.0 - b2 ** t
    inv = 1.0 / (math.sqrt(bc2) if type(bc2) is float else np.sqrt(bc2))  # numpy scalars keep numpy's rules
    c = _adam_constants(b1, b2, eps)
    return c[0], c[1], c[2], c[3], (_F64 if fp64 else _F32)(inv), c[4], _F32(-lr / bc1)


class DeviceTrainer:
    """Device-resident parameters, moments, statistics and images of one fit (module docstring).

    backend: an OpenCLBackend; images: the training images [H,W,3]; adam: "auto" | "kernel" |
    "numpy"; profile: None or a dict that collects wall seconds per phase (with a queue finish
    around each, which costs a little) and device milliseconds per kernel stage ("device_ms")."""

    # clFlush after each forward's enqueues: drivers that batch commands until a flush or a blocking
    # call (NVIDIA's OpenCL is said to) then start the rasterizer while the host enqueues the rest of
    # the step, instead of at the step's final wait. Costs one cheap call; bench/peer_step.py
    # --no-flush measures it off.
    flush_after_forward = True
    # adam_step (adam="kernel"): all groups of a call in one adam_step_multi launch (a launch costs
    # ~10 us of queue latency on an H100); False: one launch per group (adam_step / adam_step_flat),
    # the same bits (tests/test_adam_multi.py)
    adam_multi = True
    # backward(v_depth_opacity=): the announced opacity-only backward's records made in this pass
    # (RASTER_BWD_DEPTH_O, the same bits; one rasterize_bwd fewer per step of a shared soft depth
    # term); False: that backward runs its own pass
    fuse_soft_backward = True

    def __init__(self, backend, images, adam: str = "auto", profile: dict | None = None):
        import pyopencl as cl

        if adam not in ADAM_LOCATIONS:
            raise ValueError(f"adam must be one of {ADAM_LOCATIONS}, got {adam!r}")
        self.cl = cl
        self.b = backend
        self.handle = backend.handle
        self.queue = backend.queue
        self.mem = Scratch(self.handle)
        self.fp64 = backend.fp64  # cl_khr_fp64
        self.adam = adam if adam != "auto" else (CPU_DEFAULT_ADAM if backend.cpu else "kernel")
        if backend.cpu:
            # one launch per group on CPU devices (the same bits): PoCL runs adam_step_multi's 2-D work-groups
            # ~4x slower than the per-group kernels (2 Xeon cores, 54k Gaussians at SH degree 1: Adam 10.8 ->
            # 2.6 ms of device time, the step's wall 0.948x in one process; docs/perf_notes.md §29)
            self.adam_multi = False
        self.profile = profile
        self.photo = backend.photometric_kernels
        # one build; the loads first on GPUs only (adam.cl's ADAM_LOADS_FIRST: the same bits, one memory round
        # trip per element on NVIDIA, a crash of PoCL 3.0's adam_step_multi)
        adam_defs = {"ADAM_FP64": int(self.fp64), "ADAM_MULTI_SPLIT": int(bool(backend.cpu)),
                     "ADAM_LOADS_FIRST": int(not backend.cpu)}
        # adam_step_multi steps the SH groups' strided gradient views flat on GPUs (every lane busy, p / m / v
        # contiguous; docs/perf_notes.md §19), in lines of rows on CPUs (PoCL vectorizes along a row); the same bits
        self.adam_flat_views = not backend.cpu
        self.k_adam = backend.kernel("adam.cl", "adam_step", **adam_defs)
        self.k_adam_flat = backend.kernel("adam.cl", "adam_step_flat", **adam_defs)
        # built here where it is the default (GPUs: no build on the training clock), on first use elsewhere
        # (CPU devices step one group per launch: adam_multi False above)
        self._adam_defs = adam_defs
        self.k_adam_multi = None if backend.cpu else backend.kernel("adam.cl", "adam_step_multi", **adam_defs)
        self._adam_multi_wg = None  # its CL_KERNEL_WORK_GROUP_SIZE, queried once
        self.k_reg_count = backend.kernel("regularize.cl", "regularize_opacity_count", REGULARIZE_FP64=int(self.fp64))
        # regularize_grads: 8 Gaussians per work-item on CPUs (REG_VW; PoCL calls exp once per lane vector)
        self.reg_vw = REG_VW_CPU if backend.cpu else 1
        self.k_reg_grads = backend.kernel("regularize.cl", "regularize_grads", REGULARIZE_FP64=int(self.fp64),
                                          REG_VW=self.reg_vw)
        self.k_accumulate = backend.kernel("densify_accumulate.cl", "densify_accumulate", DENSIFY_FP64=int(self.fp64))
        self.k_decay = backend.kernel("regularize.cl", "opacity_decay", REGULARIZE_FP64=int(self.fp64))
        self.k_reg_value = backend.kernel("regularize.cl", "regularize_value", REGULARIZE_FP64=int(self.fp64))
        self.k_mse_rows = backend.kernel("mse.cl", "mse_rows", MSE_FP64=int(self.fp64))
        self._reg_value = None  # (sums buffer, chunks, n, weights) of the last regularize(value=True)
        self._reg_counts, self._reg_pair = None, 0  # regularize's two pairs of opacity counts, the next one
        self.k_gather_rows = backend.kernel("gather_rows.cl", "gather_rows")
        self._none_idx = None  # a one-entry index buffer holding -1 (`_zero`)
        self.k_bg_alpha = backend.kernel("bg_alpha.cl", "bg_alpha_grad")
        self.k_dm_grad = backend.kernel("depth_metric.cl", "depth_metric_grad")
        self.k_dm_rows = backend.kernel("depth_metric.cl", "depth_metric_rows")
        self.dm: list = []  # per view: (weight buffer, S = sum of its valid weights) or None (upload_depth_metric)
        self._dm_last = None  # (frame and target buffers, W, H, scale) of the last depth_metric call, for read_depth_metric
        self.k_cw_grad = backend.kernel("cross_warp.cl", "cross_warp_grad")
        self.k_cw_rows = backend.kernel("cross_warp.cl", "cross_warp_rows")
        self._cw_geom: dict = {}  # (view, partner) -> (camera, partner camera, kernel geometry arguments)
        self._cw_last: list = []  # (geometry, image buffers, H, W, scale) of the cross_warp calls since the last
        # forward (one per level), for read_cross_warp
        self._cw_blur: dict = {}  # (view, sigma) -> the blurred training image's buffer (cross_warp's blur levels)
        self._held_depth = 0  # hold_depth calls: a held depth is valid while its count is the last
        self.bg: list = []  # per view: (mask buffer, float32 2 / count) or None (upload_bg_masks)
        self.real = _F64 if self.fp64 else _F32
        # backward(stats=True) adds the statistics in project_bwd where they are double (no float32
        # division or square root in them); float ones are densify_accumulate.cl's (correctly rounded)
        self.fuse_stats = self.fp64
        self.l1_wg = 1 if backend.cpu else 64  # L1-only loss work-group (kernels/l1.cl)
        self.k_l1_rows = backend.kernel("l1.cl", "l1_rows", L1_WG=self.l1_wg)
        self.k_l1_total = backend.kernel("l1.cl", "l1_total", L1_WG=self.l1_wg)
        # ("l1", n, w_l1, rows) after an L1-only photometric pass, ("ssim",) after a full one (whose
        # PhotometricCL refuses read_loss after a value=False pass), None before any
        self._loss = None
        self.gt = []
        self.images = list(images)  # as given: the blur levels are made from them (cross_warp)
        for i, im in enumerate(self.images):
            a = np.ascontiguousarray(im, _F32)
            buf = self.mem.get("pixel", f"gt{i}", a.shape[0] * a.shape[1], 12)
            cl.enqueue_copy(self.queue, buf, a)
            self.gt.append(buf)
        self.n, self.kmax = 0, 1
        self.geometry = next(_GEOMETRY)  # the means' version in the depth order key (module docstring)
        self._cols = _columns(1)
        self._bufs: dict = {}  # (kind, name) -> buffer of the current n / kmax (cleared by upload)
        self._tmp = np.empty(0, _F32)  # numpy Adam scratch
        self._scalar = np.empty(1, _F32)  # read_loss's host word (no allocation per step)
        self.dloss = None  # the backend's DepthLossCL, set by upload_depth_targets
        self.dt: list = []  # depth target buffers per view (None: no target)
        self.dt_host: list = []  # their float32 host copies (upload_depth_metric)
        self._events: list = []  # (stage, event) of this trainer's own kernels (profile only)
        self._vw_edges: dict = {}  # (view, s, H, W) -> the view_warp term's edge weights of training image `view`
        # (at scale s > 1: of its pooled image, H, W the s-grid's)
        self._vw_images: dict = {}  # (view, s, H, W) -> training image `view` pooled over s x s (view_warp at 1/s)

    # {{{ plumbing
    def buf(self, kind: str, name: str):
        """The device buffer of parameter / moment `name` (kind "p", "m" or "v") or statistic."""
        b = self._bufs.get((kind, name))
        if b is None:
            row = 4 if kind == "stat" else 4 * self._cols[name]
            b = self._bufs[(kind, name)] = self.mem.get("gauss", f"{kind}_{name}", self.n, max(row, 1))
        return b

    def _call(self, k, gsize, lsize, *args):
        """k(queue, gsize, lsize, *args) through pyopencl's typed invoker (program.typed_invoker)."""
        if not getattr(k, "_reings_typed", False):
            typed_invoker(k, args)
        return k(self.queue, gsize, lsize, *args)

    def _write(self, buf, a: np.ndarray) -> None:
        a = np.ascontiguousarray(a)
        if a.nbytes:
            self.cl.enqueue_copy(self.queue, buf, a)  # blocking

    def _read(self, buf, shape, dtype) -> np.ndarray:
        out = np.empty(shape, dtype)
        if out.size:
            self.cl.enqueue_copy(self.queue, out, buf)  # blocking
        return out

    def _read_async(self, buf, shape, dtype, held: list) -> np.ndarray:
        """A non-blocking read into a fresh array, valid after the next queue.finish(); its event
        goes to `held`, to be dropped after that wait (pyopencl waits for a non-blocking copy's
        event when it is dropped: docs/perf_notes.md §8)."""
        out = np.empty(shape, dtype)
        if out.size:
            held.append(self.cl.enqueue_copy(self.queue, out, buf, is_blocking=False))
        return out

    def _write_async(self, buf, a: np.ndarray, held: list) -> None:
        """A non-blocking write; the host array and the event go to `held`, which must live (the
        array unchanged) until the next queue.finish()."""
        a = np.ascontiguousarray(a)
        if a.nbytes:
            held.append((a, self.cl.enqueue_copy(self.queue, buf, a, is_blocking=False)))

    def _launch(self, stage: str, k, n: int, *args):
        ev = self.b.launch(k, n, *args)
        if ev is not None and self.profile is not None:
            self._events.append((stage, ev))
        return ev

    @contextmanager
    def _map(self, buf, shape, dtype=_F32, write: bool = True):
        cl = self.cl
        count = int(np.prod(shape, dtype=np.int64))
        if count == 0:
            yield np.empty(shape, dtype)
            return
        flags = cl.map_flags.READ | (cl.map_flags.WRITE if write else 0)
        arr, _ = cl.enqueue_map_buffer(self.queue, buf, flags, 0, shape, dtype, is_blocking=True)
        try:
            yield arr
        finally:
            arr.base.release(self.queue)

    def finish(self) -> None:
        """Trainer.finish: wait for the queue; with profiling on, fold the stage times of the
        backend's and this trainer's events into profile["device_ms"]."""
        self.queue.finish()
        if self.profile is None:
            return
        dm = self.profile.setdefault("device_ms", {})
        self.b.collect_profile()
        for st, ms in self.b.last_profile.items():
            dm[st] = dm.get(st, 0.0) + ms
        for st, ev in self._events:
            try:
                dm[st] = dm.get(st, 0.0) + (ev.profile.end - ev.profile.start) * 1e-6
            except Exception:  # profiling unavailable
                pass
        self._events = []

    def device_span_ms(self) -> float | None:
        """Milliseconds from the first kernel start to the last kernel end over the commands
        recorded since the last `finish` (the backend's and this trainer's; profiling on): waits
        for the queue. None when profiling is unavailable."""
        evs = [ev for _, ev, _ in self.b.pending_events()] + [ev for _, ev in self._events]
        self.queue.finish()
        try:
            starts = [e.profile.start for e in evs]
            ends = [e.profile.end for e in evs]
            return (max(ends) - min(starts)) * 1e-6 if evs else None
        except Exception:  # profiling unavailable
            return None

    def phase(self, name: str):
        """Trainer.phase: wall time of a block into profile[name] (queue finished before and
        after); without profiling a shared no-op context (a generator context costs ~2.5 us per
        block, a dozen blocks per iteration)."""
        return _NO_PHASE if self.profile is None else self._phase(name)

    @contextmanager
    def _phase(self, name: str):
        self.finish()
        t = time.perf_counter()
        try:
            yield
        finally:
            self.finish()
            self.profile[name] = self.profile.get(name, 0.0) + time.perf_counter() - t
    # }}}

    # {{{ state transfer
    def upload(self, state) -> None:
        """Trainer.upload: parameters, moments and statistics of `state` (a TrainState) -> the
        device (at the start, or after a host-side edit of the rows)."""
        if ACCUM not in state.stats:
            state.stats.update(zero_stats(len(state)))
        self.n = len(state)
        self.kmax = 1 + state.params["sh_rest"].shape[1]
        self._cols = _columns(self.kmax)
        self._bufs = {}
        held: list = []  # the non-blocking writes' host arrays and events, alive until the one wait below
        for b, arrays, key, _, dt in self._state_slots(state):
            self._write_async(b, np.asarray(arrays[key], dt), held)
        self.queue.finish()  # one wait for the 21 copies (the caller may change its arrays after)
        held.clear()
        self.means_written()

    def means_written(self) -> None:
        """The means buffer was (or will be, before the next forward) written: forwards from now
        on sort their depth order afresh (a new geometry version; module docstring)."""
        self.geometry = next(_GEOMETRY)

    def order_key(self, cam, near: float) -> tuple:
        """The backend's depth order key of a forward of `cam` at `near` (module docstring): equal
        exactly when the projection sees the same camera-space z of every Gaussian (the camera
        record's z row and near are these float32 values)."""
        row = np.asarray(cam.viewmat, np.float64)[2, :4].astype(_F32)
        return self.geometry, row.tobytes(), _F32(near).tobytes()

    def _slots(self, params_only: bool = False) -> list:
        """(kind, key, shape at this trainer's N, dtype) of every array the trainer keeps: each
        group's parameters ("p") and both Adam moments ("m", "v"), then the three densification
        statistics ("stat"); params_only: the parameters alone. The one list upload, download and
        apply_rows walk."""
        n, km = self.n, self.kmax
        out = []
        for name in PARAM_NAMES:
            shp = _shape(name, n, km)
            out += [("p", name, shp, _F32)] + ([] if params_only else [("m", name, shp, _F32), ("v", name, shp, _F32)])
        if not params_only:
            out += [("stat", key, (n,), dt) for key, dt in ((ACCUM, _F32), (COUNT, _I32), (RADII, _F32))]
        return out

    def _state_slots(self, state, params_only: bool = False) -> list:
        """(device buffer, the dict of `state` that holds its host array, key, shape, dtype) of
        `_slots`."""
        where = {"p": state.params, "m": state.adam.exp_avg, "v": state.adam.exp_avg_sq, "stat": state.stats}
        return [(self.buf(kind, key), where[kind], key, shp, dt) for kind, key, shp, dt in self._slots(params_only)]

    def apply_rows(self, plan, zero_stats: bool = False) -> None:
        """Trainer.apply_rows: the trainer's rows become the RowPlan `plan` (reings.types) of its
        rows, on the device: per parameter, moment and statistic buffer one gather
        (kernels/gather_rows.cl: source rows for the parameters, the kept rows or zeros for the
        moments and statistics) into scratch, the plan's fresh rows written over it, and one device
        copy into the buffer (grown when the plan has more rows). Uploads only the row indices and
        the fresh rows (the split children's means and scales): the same bits as
        reference_state.apply_rows on the downloaded state (tests/test_apply_rows.py)."""
        plan.check(self.n, {k: _shape(k, 1, self.kmax)[1:] for k in PARAM_NAMES})
        n_new = len(plan)
        src = np.asarray(plan.src).astype(_I32)
        kept = np.concatenate([src[:plan.n_kept], np.full(n_new - plan.n_kept, -1, _I32)])
        slots = [(kind, key, self.buf(kind, key), int(np.prod(shp[1:], dtype=np.int64)))
                 for kind, key, shp, _ in self._slots()]
        held: list = []  # the non-blocking writes' host arrays and events, alive until the one wait below
        if n_new:
            ib = {"p": self.mem.get("gauss", "rows_src", n_new, 4)}
            self._write_async(ib["p"], src, held)
            if plan.n_kept < n_new:
                ib["m"] = self.mem.get("gauss", "rows_kept", n_new, 4)
                self._write_async(ib["m"], kept, held)
            tmp = self.mem.get("gauss", "rows_tmp", n_new, 4 * max(w for *_, w in slots))
        gathered = []
        for kind, key, b, w in slots:
            if not w:  # sh_rest at SH degree 0: no columns
                continue
            if not n_new or (kind == "stat" and zero_stats):
                gathered.append((kind, key, w, None))
                continue
            idx = ib["p"] if kind == "p" else ib.get("m", ib["p"])
            self._launch("apply_rows", self.k_gather_rows, n_new * w, _U32(n_new * w), _U32(w), idx, b, tmp)
            if kind == "p" and key in plan.fresh and n_new > plan.fresh_start:
                rows = np.ascontiguousarray(plan.fresh[key], _F32)
                held.append((rows, self.cl.enqueue_copy(self.queue, tmp, rows, dst_offset=4 * w * plan.fresh_start,
                                                        is_blocking=False)))
            nb = self.mem.get("gauss", f"{kind}_{key}", n_new, 4 * max(w, 1))  # grown if need be (the old
            # buffer is released once the gather above has read it)
            self.cl.enqueue_copy(self.queue, nb, tmp, byte_count=4 * n_new * w)
            gathered.append((kind, key, w, nb))
        self.n = n_new
        self._bufs = {}
        for kind, key, w, nb in gathered:
            if nb is None and n_new:  # zero statistics
                self._zero(self.buf(kind, key), n_new * w)
        self.queue.finish()  # one wait (the fresh rows' host arrays may change after)
        held.clear()
        self.means_written()

    def read_columns(self, params, stats=()) -> tuple[dict, dict]:
        """Trainer.read_columns: fresh host copies of some parameters and statistics of the device
        state (non-blocking reads, one wait): the columns the densification decides from."""
        want = set(params) | set(stats)
        out: dict = {"p": {}, "stat": {}}
        held: list = []
        for kind, key, shp, dt in self._slots():
            if kind in out and key in want:
                out[kind][key] = self._read_async(self.buf(kind, key), shp, dt, held)
        self.queue.finish()
        held.clear()
        return out["p"], out["stat"]

    def write_params(self, arrays: dict) -> None:
        """Trainer.write_params: host parameter columns (name -> [N, ...]) -> the device state."""
        for k, a in arrays.items():
            a = np.ascontiguousarray(a, _F32)
            if a.shape != _shape(k, self.n, self.kmax):
                raise ValueError(f"write_params: {k!r} of shape {a.shape}, expected {_shape(k, self.n, self.kmax)}")
            self._write(self.buf("p", k), a)
        if "means" in arrays:
            self.means_written()

    def reset_opacity(self, cap_logit: float) -> None:
        """Trainer.reset_opacity: 3DGS's opacity reset, logits <- min(logits, cap)
        (reference_state.opacity_cap_ on the read column, written back) and the opacities' Adam
        moments zeroed on the device."""
        o = self.read_columns(("opacity_logits",))[0]["opacity_logits"]
        opacity_cap_(o, cap_logit)
        self.write_params({"opacity_logits": o})
        for kind in ("m", "v"):
            self._zero(self.buf(kind, "opacity_logits"), self.n)

    def _zero(self, buf, n_words: int) -> None:
        """Zero the first n_words 32-bit words of `buf`: gather_rows of one row of n_words words from
        source row -1 (a kernel write: Oclgrind's uninitialised-value check does not count a fill
        buffer's bytes as written)."""
        if n_words:
            if self._none_idx is None:
                self._none_idx = self.mem.get("small", "rows_none", 1, 4)
                self._write(self._none_idx, np.full(1, -1, _I32))
            self._launch("apply_rows", self.k_gather_rows, n_words, _U32(n_words), _U32(n_words), self._none_idx,
                         self._none_idx, buf)  # the source is never read

    def download(self, state, params_only: bool = False) -> None:
        """Trainer.download: the device state -> `state` (fresh arrays; step counts and iteration
        are the host's)."""
        held: list = []  # non-blocking reads into fresh arrays, one wait at the end
        for b, arrays, key, shp, dt in self._state_slots(state, params_only):
            arrays[key] = self._read_async(b, shp, dt, held)
        self.queue.finish()
        held.clear()

    def read_params(self, names) -> dict:
        """Trainer.read_params: blocking reads of the parameter buffers."""
        return {k: self._read(self.buf("p", k), _shape(k, self.n, self.kmax), _F32) for k in names}

    def importance(self, cameras, background, near: float) -> np.ndarray:
        """Trainer.importance: Omega_G (ReInGS Eq. 7) of the device state over `cameras`, float64 [N]:
        per camera a forward of the resident parameters with the importance reduce (SH DC only:
        colours do not enter alpha*T) and one read of its [N] float32 sums, added in camera order on
        the host, the same bits as reings.rendering.gaussian_importance of the downloaded state
        (tests/test_prune_unseen.py) without uploading the Gaussians or reading the images back per
        camera. Frames go to slot 0 (as `forward`)."""
        omega = np.zeros(self.n, np.float64)
        held: list = []
        sums = []  # non-blocking reads (the in-order queue reads each before the next forward), one wait
        for cam in cameras:
            fr = self.b.forward_device(self._inputs(1), self.n, 1, cam, background, near,
                                       order_key=self.order_key(cam, near), importance=True)
            if self.n:
                sums.append(self._read_async(fr.bufs["importance"], (self.n,), _F32, held))
        self.queue.finish()
        held.clear()
        for x in sums:
            omega += x
        return omega
    # }}}

    # {{{ one pass
    def _inputs(self, k: int) -> dict:
        """backend.forward_device's parameter buffers: the SH read in place from sh_dc and sh_rest
        (project.cl's sh_in_t; the first k - 1 rows of sh_rest are the active ones)."""
        return {"means": self.buf("p", "means"), "quats": self.buf("p", "quats"),
                "log_scales": self.buf("p", "log_scales"), "opacity_logits": self.buf("p", "opacity_logits"),
                "sh": self.buf("p", "sh_dc"), "sh_rest": self.buf("p", "sh_rest"), "sh_rest_stride": 3 * (self.kmax - 1)}

    def forward(self, cam, k: int, background, near: float, opacity_override: float | None = None,
                drop=None, keep: bool = False):
        """Trainer.forward: project / bin / sort / rasterize the device parameters (k active SH
        coefficients; drop: DropGaussian's mask, kept by the frame for its backward); the frame is
        the backend's, in its frame slot 0 (valid until the next forward), or with keep=True in
        its slot 1 (valid until the next forward with keep=True; backend.forward_device)."""
        if not 1 <= k <= self.kmax:
            raise ValueError(f"active SH coefficients {k} outside [1, {self.kmax}]")
        fr = self.b.forward_device(self._inputs(k), self.n, k, cam, background, near, opacity_override, drop, keep,
                                   order_key=self.order_key(cam, near))
        self._cw_last = []  # read_cross_warp sums the levels of one frame: those called after this forward
        if self.flush_after_forward:
            self.queue.flush()  # submit the rasterizer now; the host goes on enqueuing loss / backward / Adam
        return fr

    def read_depth(self, fr) -> np.ndarray:
        """The frame's depth image [H,W] (a blocking read; the training passes never call it)."""
        return self._read(fr.bufs["out_depth"], (fr.height, fr.width), _F32)

    def upload_depth_targets(self, targets, shapes, smooth: bool = False, weights=None) -> None:
        """Trainer.upload_depth_targets: the depth targets of the training views ([H,W] each, or
        None) -> float32 device buffers, once per fit; `shapes` the views' (H, W), checked. smooth:
        also the edge weights of the depth_smooth term (DepthSmoothWeights), two more [H,W]
        buffers per view. weights: None or per view None / [H,W] per-pixel depth-loss weights, one
        more buffer per weighted view."""
        self.dloss = self.b.depth_loss_kernels
        self.dt = []
        self.dt_host = []  # per view: the float32 target as uploaded (upload_depth_metric's S), or None
        self.ds = []  # per view: (wx_buf, wy_buf, 1 / sum of weights) or None
        self.dw = []  # per view: the per-pixel weight buffer or None
        weights = [None] * len(targets) if weights is None else list(weights)
        if len(weights) != len(targets):
            raise ValueError(f"{len(weights)} depth weights for {len(targets)} depth targets")
        for i, (t, hw, wt) in enumerate(zip(targets, shapes, weights)):
            if t is None:
                self.dt.append(None)
                self.dt_host.append(None)
                self.ds.append(None)
                self.dw.append(None)
                continue
            a = np.ascontiguousarray(t, _F32)
            self.dt_host.append(a)
            if a.shape != tuple(hw):
                raise ValueError(f"depth target {i} has shape {a.shape}, its view is {tuple(hw)}")
            buf = self.mem.get("pixel", f"dt{i}", a.shape[0] * a.shape[1], 4)
            self._write(buf, a)
            self.dt.append(buf)
            if wt is None:
                self.dw.append(None)
            else:
                wa = np.ascontiguousarray(wt, _F32)
                if wa.shape != a.shape:
                    raise ValueError(f"depth weight {i} has shape {wa.shape}, its view is {tuple(hw)}")
                wbuf = self.mem.get("pixel", f"dw{i}", wa.size, 4)
                self._write(wbuf, wa)
                self.dw.append(wbuf)
            if smooth:
                sw = DepthSmoothWeights(a)
                bx = self.mem.get("pixel", f"dswx{i}", a.size, 4)
                by = self.mem.get("pixel", f"dswy{i}", a.size, 4)
                self._write(bx, sw.wx)
                self._write(by, sw.wy)
                self.ds.append((bx, by, sw.inv_sum))
            else:
                self.ds.append(None)

    def depth_loss(self, fr, view: int, p_local: int, p_global: int, margin: float, w_local: float,
                   w_global: float, w_smooth: float = 0.0):
        """Trainer.depth_loss: DNGaussian's depth loss (DepthLossCL) of the frame's depth buffer
        against the resident depth target of `view`, plus w_smooth times the depth_smooth term
        (needs upload_depth_targets(smooth=True)): dL/d depth goes into the v_depth buffer
        (returned, overwritten); the loss stays on the device (`read_depth_loss`). Nothing crosses
        the bus."""
        v = self.mem.get("pixel", "v_depth", fr.width * fr.height, 4)
        self.b.discard_held_records()  # the buffer an announced backward may hold records of is rewritten
        sm = None
        if w_smooth:
            if self.ds[view] is None:
                raise RuntimeError("depth smoothness needs upload_depth_targets(..., smooth=True)")
            bx, by, inv = self.ds[view]
            sm = (bx, by, w_smooth * inv)
        ev = self.dloss.enqueue(fr.bufs["out_depth"], self.dt[view], v, fr.height, fr.width, p_local, p_global,
                                margin, w_local, w_global, sm, self.dw[view])
        if self.profile is not None:
            self._events.append(("depth_loss", ev))  # last kernel only: a lower bound
        return v

    def read_depth_loss(self) -> float:
        """Trainer.read_depth_loss: one blocking read of two scalars."""
        return self.dloss.read_loss()

    def read_rgb(self, fr) -> np.ndarray:
        """Trainer.read_rgb: a blocking read of the frame's image."""
        return self._read(fr.bufs["out_rgb"], (fr.height, fr.width, 3), _F32)

    def photometric(self, fr, view: int, w_l1: float, w_ssim: float, value: bool = True):
        """Trainer.photometric: L1 + SSIM of the frame's image against training image `view`
        (PhotometricCL); dL/d rgb goes into the v_rgb buffer (returned); the loss stays on the
        device (`read_loss`); value=False skips the loss's own reduction (PhotometricCL.enqueue).
        w_ssim == 0: the L1-only kernels (kernels/l1.cl, two launches, no SSIM pass at all)."""
        v = self.mem.get("pixel", "v_rgb", fr.width * fr.height, 12)
        if w_ssim == 0:
            return self.photometric_l1(fr.bufs["out_rgb"], self.gt[view], v, fr.height, fr.width, w_l1)
        ev = self.photo.enqueue(fr.bufs["out_rgb"], self.gt[view], v, fr.height, fr.width, w_l1, w_ssim, value)
        self._loss = ("ssim",)
        if self.profile is not None:
            self._events.append(("photometric_loss", ev))  # last kernel only: a lower bound
        return v

    def photometric_l1(self, x, y, v, h: int, w: int, w_l1: float = 1.0):
        """w_l1 * mean|x - y| of [h,w,3] image buffers: dL/dx into `v` (returned) and the per-row
        sums of |x - y| on the device, one launch (kernels/l1.cl l1_rows); `read_loss` reduces
        them (l1_total) and reads one scalar."""
        n = h * w * 3
        rows = self.mem.get("small", "l1_rows", max(h, 1), 4)
        wg = self.l1_wg
        if n == 0:
            self.cl.enqueue_fill_buffer(self.queue, self.mem.get("small", "l1_total", 1, 4), _F32(0), 0, 4)
            self._loss = ("l1", n, float(w_l1), 0)
            return v
        ev = self._call(self.k_l1_rows, (wg, h), (wg, 1), x, y, v, rows, _F32(w_l1 / n), _I32(3 * w), _I32(h))
        if self.profile is not None:
            self._events.append(("l1_rows", ev))
        self._loss = ("l1", n, float(w_l1), h)  # the total is reduced only when read (read_loss)
        return v

    def read_loss(self) -> float:
        """Trainer.read_loss: one blocking read (a scalar for L1-only, H x 2 partial sums for
        L1 + SSIM)."""
        if self._loss is not None and self._loss[0] == "l1":
            _, n, w_l1, h = self._loss
            total = self.mem.get("small", "l1_total", 1, 4)
            if h:  # reduce the row sums of the last pass into the scalar (not launched by passes nobody reads)
                wg = self.l1_wg
                ev = self._call(self.k_l1_total, (wg,), (wg,), self.mem.get("small", "l1_rows", h, 4), total, _I32(h))
                if self.profile is not None:
                    self._events.append(("l1_total", ev))
            t = self._scalar
            self.cl.enqueue_copy(self.queue, t, total)  # blocking
            return float(w_l1 * float(t[0]) / max(n, 1))
        return self.photo.read_loss()  # raises after a value=False pass or before any

    def backward(self, fr, v_rgb=None, v_depth=None, opacity_override: float | None = None,
                 grad_fields=None, into: dict | None = None, v_alpha=None, v_depth_opacity=None,
                 hold: bool = False, stats: bool = False) -> dict:
        """Trainer.backward of `fr` with v_rgb (a device buffer) and/or v_depth (a device buffer,
        e.g. from `depth_loss`, or a host [H,W] array, uploaded). Returns the gradient buffers
        {field: buffer} of backend.backward_device plus "sh_k" (`adam_step` reads the SH groups
        as strided views of the "sh" buffer); with `into` (from `hold`, or a backward with hold),
        project_bwd adds the `grad_fields` ones (None: all) into its buffers (its accumulate mode:
        no second launch, the same bits as a float32 add) and returns it. hold (without `into`):
        project_bwd writes the gradients straight into the held buffers `hold` would copy them into
        (no copy). The frame's
        DropGaussian mask (from `forward`) applies. v_depth_opacity (a device buffer;
        Trainer.backward): with `fuse_soft_backward`, this pass also makes the records of the
        announced opacity-only backward of that cotangent (backend.backward_device). stats: the
        densification statistics of this backward too (Trainer.backward; every field: grad_fields
        None), added by its project_bwd (no densify_accumulate launch: docs/perf_notes.md §25) where
        the statistics are double (cl_khr_fp64: no float32 division or square root in them, so the
        build options of project.cl and densify_accumulate.cl cannot tell them apart), else by
        `accumulate` after it."""
        if stats and grad_fields is not None:
            raise ValueError("backward: stats=True needs a backward of every field (grad_fields=None)")
        vd = v_depth
        if isinstance(v_depth, np.ndarray):  # its own buffer: never the depth loss's (an announced cotangent)
            vd = self.mem.get("pixel", "v_depth_host", fr.width * fr.height, 4)
            self._write(vd, np.asarray(v_depth, _F32))
        if isinstance(v_depth_opacity, np.ndarray):
            vdo_buf = self.mem.get("pixel", "v_depth_o_host", fr.width * fr.height, 4)
            self._write(vdo_buf, np.asarray(v_depth_opacity, _F32))
            v_depth_opacity = vdo_buf
        vdo = v_depth_opacity if self.fuse_soft_backward else None
        fused = stats and self.fuse_stats
        st = (self.buf("stat", ACCUM), self.buf("stat", COUNT), self.buf("stat", RADII)) if fused else None
        cols = grad_columns(fr.sh_k)
        if into is not None:  # project_bwd adds the grad_fields into the held buffers (no second launch)
            if into.get("sh_k") != fr.sh_k or set(into) != {*cols, "sh_k"}:
                raise ValueError("backward into: the held gradients are of another SH count or field set")
            self.b.backward_device(fr, v_rgb, vd, v_alpha, opacity_override, grad_fields, v_depth_opacity=vdo,
                                   out={f: into[f] for f in cols}, accumulate=True, stats=st)
            if stats and not fused:
                self.accumulate(fr)
            return into
        out = self._held(fr.sh_k) if hold else None
        g = dict(self.b.backward_device(fr, v_rgb, vd, v_alpha, opacity_override, grad_fields, v_depth_opacity=vdo,
                                        out=None if out is None else {f: out[f] for f in cols}, stats=st))
        if stats and not fused:
            self.accumulate(fr)
        g["sh_k"] = fr.sh_k
        return g

    def upload_bg_masks(self, masks) -> None:
        """Trainer.upload_bg_masks: float32 0/1 device buffers, once per fit."""
        self.bg = []
        for i, m in enumerate(masks):
            if m is None:
                self.bg.append(None)
                continue
            a = np.ascontiguousarray(np.asarray(m, bool), _F32)
            buf = self.mem.get("pixel", f"bgmask{i}", a.size, 4)
            self._write(buf, a)
            n = int(a.sum())
            self.bg.append((buf, _F32(2.0 / n) if n else _F32(0)))

    def bg_alpha(self, fr, view: int):
        """Trainer.bg_alpha: kernels/bg_alpha.cl into the v_alpha buffer (returned)."""
        buf, scale = self.bg[view]
        n = fr.width * fr.height
        v = self.mem.get("pixel", "v_alpha", n, 4)
        self._launch("bg_alpha", self.k_bg_alpha, n, _I32(n), scale, fr.bufs["out_alpha"], buf, v)
        return v

    def upload_depth_metric(self, weights) -> None:
        """Trainer.upload_depth_metric: per view None / [H,W] weights of the metric depth term (after
        upload_depth_targets: a view needs its target); S per view in float64 on the host."""
        from ..reference_loss import depth_metric_valid

        self.dm = []
        if len(weights) != len(self.dt):
            raise ValueError(f"{len(weights)} depth-metric weights for {len(self.dt)} depth targets")
        for i, (wt, t) in enumerate(zip(weights, self.dt_host)):
            if wt is None or t is None:
                self.dm.append(None)
                continue
            wa = np.ascontiguousarray(wt, _F32)
            if wa.shape != t.shape:
                raise ValueError(f"depth-metric weight {i} has shape {wa.shape}, its target {t.shape}")
            buf = self.mem.get("pixel", f"dmw{i}", wa.size, 4)
            self._write(buf, wa)
            self.dm.append((buf, float(np.sum(wa.astype(_F64)[depth_metric_valid(t, wa)]))))

    def depth_metric(self, fr, view: int, weight: float, into=None):
        """Trainer.depth_metric: kernels/depth_metric.cl's gradient of the frame's depth against the
        resident target of `view` into the trainer's v_depth buffer (returned), or added into the
        device buffer `into` (returned); the loss's row sums wait for `read_depth_metric`, which
        launches them on this frame's buffers (valid until the next forward)."""
        npx = fr.width * fr.height
        rec = self.dm[view] if view < len(self.dm) else None
        scale = _F32(weight / rec[1]) if rec is not None and rec[1] > 0 else _F32(0)
        v = into if into is not None else self.mem.get("pixel", "dm_v_depth", npx, 4)
        wbuf = rec[0] if rec is not None else None
        if wbuf is None:  # no weights: the term is zero
            if into is None:
                self.cl.enqueue_fill_buffer(self.queue, v, _F32(0), 0, 4 * npx)
            self._dm_last = None
            return v
        args = (fr.bufs["out_depth"], fr.bufs["out_alpha"], self.dt[view], wbuf)
        self._launch("depth_metric", self.k_dm_grad, npx, _I32(npx), scale, _I32(into is not None), *args, v)
        self._dm_last = (args, fr.width, fr.height, scale)
        return v

    def read_depth_metric(self) -> float:
        """Trainer.read_depth_metric: the last depth_metric call's loss: depth_metric_rows on its
        frame's buffers (valid until the next forward), then a blocking read of the H row sums,
        summed in float64; 0 when it had no weights."""
        if self._dm_last is None:
            return 0.0
        args, w, h, scale = self._dm_last
        rows = self.mem.get("small", "dm_rows", h, 4)
        self._launch("depth_metric_rows", self.k_dm_rows, h, _I32(w), _I32(h), *args, rows)
        return float(scale) * float(np.sum(self._read(rows, (h,), _F32).astype(_F64)))

    def hold_depth(self, fr) -> HeldDepth:
        """Trainer.hold_depth: device copies of the frame's depth and alpha buffers into the
        trainer's held_depth / held_alpha (the next forward, which reuses the frame slot's, leaves
        them alone), valid until the next hold_depth."""
        npx = fr.width * fr.height
        d = self.mem.get("pixel", "held_depth", max(npx, 1), 4)
        a = self.mem.get("pixel", "held_alpha", max(npx, 1), 4)
        if npx:
            self.cl.enqueue_copy(self.queue, d, fr.bufs["out_depth"], byte_count=4 * npx)
            self.cl.enqueue_copy(self.queue, a, fr.bufs["out_alpha"], byte_count=4 * npx)
        self._held_depth += 1
        return HeldDepth(d, a, fr.width, fr.height, self._held_depth)

    def cross_warp(self, fr, view: int, partner: int, partner_cam, weight: float, near: float, into=None,
                   occlusion: float = 0.0, partner_depth: HeldDepth | None = None, sigma: float = 0.0):
        """Trainer.cross_warp: kernels/cross_warp.cl's depth cotangent of the frame (a render of
        training view `view`) from training image `partner` (its camera `partner_cam`) against
        training image `view`, into the trainer's cw_v_depth buffer (returned), or added into the
        device buffer `into` (returned); occlusion > 0: the occlusion test against `partner_depth`
        (`hold_depth` of a render of `partner_cam`); sigma > 0: both training images blurred
        (`_cross_warp_image`). The loss's row sums and counts wait for `read_cross_warp`, which
        launches them on this frame's buffers (valid until the next forward) and the held depth's."""
        h, w = fr.height, fr.width
        npx = h * w
        geom = self._cross_warp_geom(view, partner, fr.camera, partner_cam, w, h, near, occlusion)
        scale = _F32(weight / (3.0 * npx)) if npx else _F32(0)
        imgs = (fr.bufs["out_depth"], fr.bufs["out_alpha"], self._cross_warp_image(view, sigma),
                self._cross_warp_image(partner, sigma))
        tol = geom[-1]  # float32, as the kernel tests it
        if tol > 0:
            pd = check_held_depth(partner_depth, partner_cam, self._held_depth)
            imgs += (pd.depth, pd.alpha)
        else:  # the test is off: the kernel reads no partner depth
            imgs += imgs[:2]
        v = into if into is not None else self.mem.get("pixel", "cw_v_depth", max(npx, 1), 4)
        self._launch("cross_warp", self.k_cw_grad, npx, *geom, scale, _I32(into is not None), *imgs, v)
        self._cw_last.append((geom, imgs, h, w, scale))
        return v

    def _cross_warp_image(self, view: int, sigma: float):
        """Training image `view`'s buffer for cross_warp's level sigma: gt<view> at 0, else
        reference_cross_warp.blur_image of the image as given (as float32, as the gt buffer holds
        it), made and uploaded at the first call of that (view, sigma) and kept for the fit."""
        sigma = float(sigma)
        if sigma == 0:
            return self.gt[view]
        buf = self._cw_blur.get((view, sigma))
        if buf is None:
            a = np.ascontiguousarray(blur_image(np.asarray(self.images[view], _F32), sigma), _F32)
            buf = self.mem.get("pixel", f"gt{view}_blur{sigma!r}", a.shape[0] * a.shape[1], 12)
            self.cl.enqueue_copy(self.queue, buf, a)  # blocking: `a` may go
            self._cw_blur[(view, sigma)] = buf
        return buf

    def _cross_warp_geom(self, view: int, partner: int, cam, partner_cam, w: int, h: int, near: float,
                         occlusion: float) -> tuple:
        """cross_warp's kernel arguments before the scale: the sizes, hm, e (cross_warp_args, kept
        per (view, partner) while the two cameras are the same objects), near, alpha_min and the
        occlusion tolerance (float32; 0: off)."""
        hit = self._cw_geom.get((view, partner))
        if hit is None or hit[0] is not cam or hit[1] is not partner_cam:
            hm, e = cross_warp_args(cam, partner_cam)
            hit = self._cw_geom[(view, partner)] = (cam, partner_cam, (*(_F32(x) for x in hm), *(_F32(x) for x in e)))
        return (_I32(w), _I32(h), _I32(partner_cam.width), _I32(partner_cam.height), *hit[2],
                _F32(near), _F32(CROSS_WARP_ALPHA_MIN), _F32(occlusion))

    def read_cross_warp(self) -> dict:
        """Trainer.read_cross_warp: the loss of the cross_warp calls since the last forward (the
        levels of one frame), valid and occluded fractions of the last one: per call cross_warp_rows
        on its frame's buffers (valid until the next forward), then blocking reads of the H row sums
        and counts, summed in float64; the calls' losses added in their order."""
        if not self._cw_last:
            raise RuntimeError("read_cross_warp before a cross_warp (since the last forward)")
        loss, out = 0.0, None
        for geom, imgs, h, w, scale in self._cw_last:
            if h * w == 0:
                out = {"loss": 0.0, "valid_fraction": 0.0, "occluded_fraction": 0.0}
                continue
            rows = self.mem.get("small", "cw_rows", h, 4)
            counts = self.mem.get("small", "cw_counts", h, 4)
            occluded = self.mem.get("small", "cw_occluded", h, 4)
            self._launch("cross_warp_rows", self.k_cw_rows, h, *geom, *imgs, rows, counts, occluded)
            total = float(np.sum(self._read(rows, (h,), _F32).astype(_F64)))
            valid = int(np.sum(self._read(counts, (h,), _I32).astype(np.int64)))
            occ = int(np.sum(self._read(occluded, (h,), _I32).astype(np.int64)))
            out = {"loss": float(scale) * total, "valid_fraction": valid / (h * w), "occluded_fraction": occ / (h * w)}
            loss += out["loss"]
        return {**out, "loss": loss}

    def hold(self, grads: dict) -> dict:
        """Trainer.hold: device copies of the gradient buffers (trainer-owned, so the next
        backward, which reuses the backend's, leaves them alone); gradients already held (a backward
        with hold=True) are returned as they are."""
        out = self._held(grads["sh_k"])
        for f, cols in grad_columns(grads["sh_k"]).items():
            if self.n * cols and grads[f] is not out[f]:
                self.cl.enqueue_copy(self.queue, out[f], grads[f], byte_count=4 * cols * self.n)
        return out

    def _held(self, sh_k: int) -> dict:
        """The trainer-owned gradient buffers of `hold` and `backward(hold=True)` ({field: buffer, "sh_k"})."""
        out = {"sh_k": sh_k}
        for f, cols in grad_columns(sh_k).items():
            out[f] = self.mem.get("gauss", f"held_{f}", self.n, 4 * cols)
        return out

    def view_warp(self, virt, fr, view: int, baseline: float, weight: float, smooth_weight: float,
                  scale: int = 1):
        """Trainer.view_warp: ViewWarpCL.enqueue (kernels/view_warp.cl) of the kept virtual frame's
        image buffer and the frame's depth buffer against training image `view`; the cotangents go
        into trainer-owned buffers (returned); the loss stays on the device (`read_view_warp`).
        scale s > 1: the term on the s-grid (kernels/block_mean.cl): the frame's depth pooled per call,
        the training image pooled once per view and kept, focal fx / s; the s-grid depth cotangent
        spread back to the frame's resolution by block_mean_bwd (written: the first depth term)."""
        vw = self.b.view_warp_kernels
        s = check_view_warp_scale(virt, fr, scale)
        h, w = fr.height // s, fr.width // s
        npx = w * h
        v_virt = self.mem.get("pixel", "vw_v_virt", npx, 12)
        v_depth = self.mem.get("pixel", "vw_v_depth" if s == 1 else "vw_v_depth_s", npx, 4)
        depth, gt = fr.bufs["out_depth"], self.gt[view]
        if s > 1:  # the frame's depth on the s-grid (its pooled buffer valid until the next call)
            bm = self.b.block_mean_kernels
            depth = self.mem.get("pixel", "vw_depth_s", npx, 4)
            bm.fwd(fr.bufs["out_depth"], depth, fr.height, fr.width, 1, s)
            self._profiled(bm.events)
            gt = self._view_warp_image(view, s, fr.height, fr.width)
        edges = None
        if smooth_weight:  # the training image's edge weights (8 bytes a pixel): made on their first use, kept
            key = (view, s, h, w)
            edges = self._vw_edges.get(key)
            if edges is None:
                name = f"vw_edges{view}_{h}x{w}" + (f"_s{s}" if s > 1 else "")
                edges = self._vw_edges[key] = vw.edges(gt, h, w, out=self.mem.get("pixel", name, npx, 8))
                self._profiled(vw.events)
        vw.enqueue(virt.bufs["out_rgb"], depth, gt, v_virt, v_depth, h, w, fr.camera.fx / s, baseline, weight,
                   smooth_weight, edges=edges)
        self._profiled(vw.events)
        if s > 1:  # the adjoint of the depth's pooling: the frame's full-resolution depth cotangent
            full = self.mem.get("pixel", "vw_v_depth", fr.width * fr.height, 4)
            self.b.block_mean_kernels.bwd(v_depth, full, fr.height, fr.width, 1, s)
            self._profiled(self.b.block_mean_kernels.events)
            v_depth = full
        return v_virt, v_depth

    def _view_warp_image(self, view: int, s: int, height: int, width: int):
        """Training image `view` ([height, width, 3]) pooled over s x s blocks (block_mean_fwd): made on its
        first use, kept for the fit (the images never change)."""
        key = (view, s, height, width)
        buf = self._vw_images.get(key)
        if buf is None:
            bm = self.b.block_mean_kernels
            name = f"vw_gt{view}_{height}x{width}_s{s}"
            buf = self._vw_images[key] = self.mem.get("pixel", name, (height // s) * (width // s), 12)
            bm.fwd(self.gt[view], buf, height, width, 3, s)
            self._profiled(bm.events)
        return buf

    def _profiled(self, events) -> None:
        """Keep a helper's (kernel, event) pairs for the profile (profile only)."""
        if self.profile is not None:
            self._events.extend(events)

    def read_view_warp(self) -> dict:
        """Trainer.read_view_warp: one small reduction and a 12-byte read."""
        st = self.b.view_warp_kernels.read_stats()
        return {"loss": st["loss"], "valid_fraction": st["valid_fraction"]}

    def opacity_decay(self, factor: float) -> None:
        """Trainer.opacity_decay: kernels/regularize.cl opacity_decay on the logits buffer."""
        f = float(factor)
        if not 0.0 < f <= 1.0:
            raise ValueError(f"opacity_decay: factor must lie in (0, 1], got {factor!r}")
        if f == 1.0 or self.n == 0:
            return
        r = self.real
        self._launch("opacity_decay", self.k_decay, self.n, _I32(self.n), r(np.log(f)), r(1.0 - f),
                     self.buf("p", "opacity_logits"))

    def regularize(self, grads: dict, shape_pena: float, scale_pena: float, opa_pena: float,
                   value: bool = False) -> None:
        """Trainer.regularize: kernels/regularize.cl adds the penalties' gradients into `grads`;
        value: also their per-chunk sums at the parameters now (regularize_value), left on the
        device for `read_regularize`."""
        weights = (shape_pena, scale_pena, opa_pena)
        if value:
            self._reg_value = (None, 0, self.n, weights)
        if not (shape_pena or scale_pena or opa_pena) or self.n == 0:
            return
        if value:
            chunks = -(-self.n // REG_VALUE_CHUNK)
            sums = self.mem.get("small", "reg_value", chunks * REG_VALUE_COLS, np.dtype(self.real).itemsize)
            self._launch("regularize_value", self.k_reg_value, chunks, _I32(self.n), _I32(REG_VALUE_CHUNK),
                         self.buf("p", "log_scales"), self.buf("p", "opacity_logits"), sums)
            self._reg_value = (sums, chunks, self.n, weights)
        if self._reg_counts is None:  # two pairs of counters, zero; regularize_grads zeroes the next one
            self._reg_counts = self.mem.get("small", "reg_counts", 4, 4)
            self.cl.enqueue_fill_buffer(self.queue, self._reg_counts, _I32(0), 0, 16)
        counts, pair = self._reg_counts, self._reg_pair
        if opa_pena:
            chunk = REG_COUNT_CHUNK_CPU if self.b.cpu else REG_COUNT_CHUNK_GPU
            self._launch("regularize_opacity_count", self.k_reg_count, -(-self.n // chunk), _I32(self.n),
                         _I32(chunk), self.buf("p", "opacity_logits"), counts, _I32(pair))
        r = self.real
        self._launch("regularize_grads", self.k_reg_grads, -(-self.n // self.reg_vw), _I32(self.n),
                     self.buf("p", "log_scales"), self.buf("p", "opacity_logits"), counts, _I32(pair),
                     r(shape_pena), r(scale_pena), r(opa_pena), grads["log_scales"], grads["opacity_logits"])
        if opa_pena:
            self._reg_pair = 1 - pair

    def read_regularize(self) -> float:
        """Trainer.read_regularize: the last regularize(value=True)'s penalties (a blocking read of
        its per-chunk sums, added in float64: reference_loss.regularize_value)."""
        if self._reg_value is None:
            raise RuntimeError("read_regularize before a regularize(..., value=True)")
        sums, chunks, n, weights = self._reg_value
        host = np.zeros((0, REG_VALUE_COLS)) if sums is None else self._read(sums, (chunks, REG_VALUE_COLS), self.real)
        return regularize_value(host, n, *weights)

    def read_mse(self, fr, view: int) -> float:
        """Trainer.read_mse: kernels/mse.cl's row sums of the frame's image against training image
        `view` (one launch and a blocking read of H words), added in float64 / 3HW."""
        h, w = fr.height, fr.width
        if h * w == 0:
            return float("nan")  # numpy's mean of nothing
        rows = self.mem.get("small", "mse_rows", h, np.dtype(self.real).itemsize)
        self._launch("mse_rows", self.k_mse_rows, h, _I32(w), _I32(h), fr.bufs["out_rgb"], self.gt[view], rows)
        return float(np.sum(self._read(rows, (h,), self.real).astype(_F64)) / (3 * h * w))

    def accumulate(self, fr) -> None:
        """Trainer.accumulate: kernels/densify_accumulate.cl on the frame's radii and v_proj."""
        r = self.real
        self._launch("densify_accumulate", self.k_accumulate, self.n, _I32(self.n), fr.bufs["radii"], fr.bufs["v_proj"],
                     r(0.5 * fr.width), r(0.5 * fr.height), self.buf("stat", ACCUM), self.buf("stat", COUNT),
                     self.buf("stat", RADII))

    def _grad_view(self, grads: dict, name: str):
        """(buffer, stride, offset, columns) of group `name`'s gradient in the backward's buffers."""
        k = grads["sh_k"]
        if name == "sh_dc":
            return grads["sh"], 3 * k, 0, 3
        if name == "sh_rest":
            return grads["sh"], 3 * k, 3, 3 * (k - 1)
        c = self._cols[name]
        return grads[name], c, 0, c

    def adam_step(self, opt, grads: dict, groups) -> None:
        """Trainer.adam_step: one Adam step of each group in `groups` with `opt`'s lrs, betas, eps
        and step counts (the counts are advanced here, as reings.optim.Adam does, including for
        empty groups): kernels/adam.cl, or adam_update on the mapped buffers. The kernel steps every
        non-empty group of the call in one launch (`_adam_multi`; a group named twice starts a
        second launch), or with `adam_multi` False one launch per group (`_adam_group`)."""
        n = self.n
        multi = self.adam == "kernel" and self.adam_multi
        batch: list = []  # the groups of the next adam_step_multi launch
        named: set = set()  # their names
        try:
            for name in groups:
                if name not in opt.lr:
                    raise KeyError(f"adam_step: {name!r} is not a parameter group ({opt.groups})")
                if multi and (len(batch) == ADAM_SLOTS or name in named):
                    pending, batch = batch, []
                    named = set()
                    self._adam_multi(opt, pending)  # a repeated group steps after its first step
                t = opt.state.step[name] + 1
                opt.state.step[name] = t
                cols = self._cols[name]
                if n * cols == 0:
                    continue
                view = self._grad_view(grads, name)
                if multi:
                    batch.append((name, t, view))
                    named.add(name)
                elif self.adam == "kernel":
                    self._adam_group(opt, name, t, view)
                else:
                    self._adam_numpy(name, _shape(name, n, self.kmax), *view, opt.lr[name], t, opt)
                if name == "means":
                    self.means_written()
        except Exception:
            pending, batch = batch, []
            self._adam_multi(opt, pending)  # the groups before the failing one are stepped, as one launch each was
            raise
        self._adam_multi(opt, batch)

    def _adam_multi(self, opt, batch: list) -> None:
        """One kernels/adam.cl adam_step_multi launch stepping the groups of `batch` ((name, step
        count, gradient view) each, non-empty, distinct, at most ADAM_SLOTS), slots in `batch`'s
        order, unused slots with the last one's buffers and no work-groups. Work-groups of lx x ly
        lanes, lx the strided groups' widest row padded to 16 (so one row fits a line: no index
        division), ly from the backend's work-group size; a strided group narrower than half a line
        puts several rows in a line (1 << sh lanes each, the row width's next power of two)."""
        if not batch:
            return
        n = self.n
        views = []
        wide = 1
        for name, t, (g, gs, go, gc) in batch:
            cols = self._cols[name]
            flat = gs == cols and go == 0 and gc == cols
            views.append((name, t, g, gs, go, gc, cols, flat))
            if not flat and not self.adam_flat_views:
                wide = max(wide, cols)
        lx = -(-wide // ADAM_LX) * ADAM_LX
        if self.k_adam_multi is None:
            self.k_adam_multi = self.b.kernel("adam.cl", "adam_step_multi", **self._adam_defs)
        if self._adam_multi_wg is None:  # the kernel's own limit (CL_KERNEL_WORK_GROUP_SIZE) bounds lx * ly too
            cl = self.cl
            self._adam_multi_wg = int(self.k_adam_multi.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                                                            self.handle.device))
        ly = max(1, min(self.b.wg, self._adam_multi_wg) // lx)
        lanes = ly * lx
        args: list = []
        end = 0
        for name, t, g, gs, go, gc, cols, flat in views:
            sc = adam_scalars(opt.lr[name], t, opt.beta1, opt.beta2, opt.eps, self.fp64)
            if flat or self.adam_flat_views:  # rows counts elements, lx of them per line (sh 1: a strided view)
                rows, rpl, sh = n * cols, 0, 0 if flat else 1
                end += -(-rows // lanes)
            else:
                sh = max(cols - 1, 0).bit_length()  # 1 << sh >= cols lanes per row
                rows, rpl = n, max(lx >> sh, 1)
                end += -(-n // (rpl * ly))
            args += (self.buf("p", name), self.buf("m", name), self.buf("v", name), g, _U32(end), _U32(rows),
                     _U32(cols), _U32(rpl), _U32(sh), _U32(gs), _U32(go), _U32(gc), sc[4], sc[6])
        last = args[-_ADAM_SLOT_ARGS:]  # unused slots: the last slot's buffers, no work-groups, zero sizes
        pad = last[:4] + [_U32(end)] + [_U32(0)] * 7 + [type(sc[4])(0), _F32(0)]
        assert len(pad) == _ADAM_SLOT_ARGS
        args += pad * (ADAM_SLOTS - len(batch))
        # b1, 1 - b1, b2, 1 - b2, eps: the optimizer's, the same in every group's adam_scalars
        ev = self._call(self.k_adam_multi, (lx * end, ly), (lx, ly), sc[0], sc[1], sc[2], sc[3], sc[5], *args)
        if self.profile is not None:
            self._events.append(("adam", ev))

    def _adam_group(self, opt, name: str, t: int, view) -> None:
        """One group's Adam step in its own launch (adam_step_flat or the strided adam_step)."""
        n, cols = self.n, self._cols[name]
        g, gs, go, gc = view
        sc = adam_scalars(opt.lr[name], t, opt.beta1, opt.beta2, opt.eps, self.fp64)
        pmv = (self.buf("p", name), self.buf("m", name), self.buf("v", name))
        if gs == cols and go == 0 and gc == cols:
            self._launch("adam", self.k_adam_flat, n * cols, _U32(n * cols), *pmv, g, *sc)
        else:
            # columns padded to ADAM_CPU_PAD in a work-group row: PoCL vectorizes along it (4x faster
            # than the runtime's choice for 45 columns)
            cpad = -(-cols // ADAM_CPU_PAD) * ADAM_CPU_PAD
            ly = max(1, 64 // cpad)
            ev = self._call(self.k_adam, (cpad, -(-n // ly) * ly), (cpad, ly), _U32(n), _U32(cols), *pmv, g,
                            _U32(gs), _U32(go), _U32(gc), *sc)
            if self.profile is not None:
                self._events.append(("adam", ev))

    def step_l1(self, cam, view: int, opt, groups=None, k: int | None = None, background=(0.0, 0.0, 0.0),
                near: float = 0.01, w_l1: float = 1.0, read_loss: bool = False):
        """One plain training step, the workload of gsplat's step in bench/peer_gsplat.py: forward
        of the device parameters (k active SH coefficients, default all), w_l1 * mean|rgb - gt|
        against training image `view` on the device (L1 only: no SSIM pass), backward, one Adam
        step of every group in `groups` (default: all of opt's). No densification statistics, no
        penalties. Host syncs: the binning's (V, K) read, plus one scalar read if read_loss.
        Returns (frame, loss or None); the queue is not finished."""
        k = self.kmax if k is None else int(k)
        fr = self.forward(cam, k, background, near)
        v = self.photometric(fr, view, w_l1, 0.0)
        grads = self.backward(fr, v)
        self.adam_step(opt, grads, opt.groups if groups is None else groups)
        return fr, (self.read_loss() if read_loss else None)

    def _adam_numpy(self, name, shp, g, gs, go, gc, lr, t, opt) -> None:
        n, cols = shp[0], int(np.prod(shp[1:], dtype=np.int64))
        if self._tmp.size < n * cols:
            self._tmp = np.empty(max(n * cols, int(self._tmp.size * 1.5)), _F32)
        tmp = self._tmp[: n * cols].reshape(shp)
        with ExitStack() as st:
            p = st.enter_context(self._map(self.buf("p", name), shp))
            m = st.enter_context(self._map(self.buf("m", name), shp))
            v = st.enter_context(self._map(self.buf("v", name), shp))
            ga = st.enter_context(self._map(g, (n, gs), write=False))[:, go:go + gc]
            if gc == cols:
                gg = ga.reshape(shp)
            else:  # inactive SH coefficients: zero gradient
                gg = np.zeros((n, cols), _F32)
                gg[:, :gc] = ga
                gg = gg.reshape(shp)
            adam_update(p, m, v, gg, lr, t, opt.beta1, opt.beta2, opt.eps, tmp)
    # }}}
