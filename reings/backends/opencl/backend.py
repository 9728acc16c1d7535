"""`OpenCLBackend`: the stage sequence of reings/backends/base.py on one OpenCL device.

    b = OpenCLBackend("pocl")                      # or "cuda", "oclgrind", "opencl:P:D"
    out = b.render(g, cam, background=(0, 0, 0), near=0.01)          # RenderOutput (+ stats)
    grads = b.render_vjp(g, cam, v_rgb, v_depth, v_alpha, ...)       # Gaussians of dL/d(field)

Stage methods with the reference's names take and return host numpy (tests, debugging):
`project_fwd`, `bin`, `rasterize_fwd`, `rasterize_bwd`, `project_bwd`. The fused `render` /
`render_vjp` keep every intermediate on the device:

    upload -> project_fwd -> depth sort (all N, keys t_z or culled by the near plane, culled last;
      or a shared order: "Depth orders" below) -> bin_count -> scan
      -> ONE blocking read of (V, K, visible) (none sync-free: "Binning" below) -> bin_emit
      -> tile sort (ceil(log2 T) bits) -> tile_ranges -> rasterize_fwd -> one final batch of reads
    render_vjp: [forward] -> rasterize_bwd -> isect_reduce -> project_bwd -> one final batch of reads

Device-resident entry points (the device trainer, reings/backends/opencl/trainer.py):
`forward_device(inp, n, sh_k, cam, ...)` runs the forward on Gaussians already in device buffers and
returns the frame; `backward_device(fr, v_rgb_buf, v_depth_buf, ...)` returns gradient buffers.
Nothing goes up per call (the camera record lives in a buffer cached per camera) and nothing but
the bin stage's counts come back (without a wait when sync-free). The trainer launches its own
kernels with `kernel` + `launch` and folds the stage times with `collect_profile` /
`pending_events`.

Binning (docs/perf_notes.md §8; reings/backends/opencl/bin_counts.py): `bin_mode` ("auto" |
"sync" | "async"; the constructor's argument, else $REINGS_BIN, else "sync": docs/results.md §26
measured no end-to-end gain on an H100 run for ~100x the memory of K) decides per forward
(`binning(n, n_tiles)`) how the binning learns V and K. sync: one blocking read, the K buffers and
launches sized by K. async (sync-free): the K buffers at the bound N * n_tiles, V and K left in the
frame slot's ctrl buffer for the kernels (bin_emit over N ranks, the tile sort and tile_ranges
launched for an estimate of K and looping to the device's, the reduces over N ranks), the counts
read back without blocking; the same bits either way. "auto" = async on non-CPU devices whose
memory holds the bound within `bin_budget` of it (argument, else $REINGS_BIN_BUDGET, else a
quarter), else sync (PoCL: sync). A frame's `visible` / `isects`
and `last_stats` resolve a sync-free read when first asked. `binned` counts the forwards per mode.
Every path that bins on the device follows the mode; `bin` (an uploaded projection) only while
its rects keep the bound.

Training (the Backend protocol of reings/backends/base.py): `trainer(images, engine, adam,
profile)` makes the device trainer (default) or the host one; `photometric_loss` / `depth_loss`
are the host forms of the loss kernels (reings/backends/opencl/losses.py, one instance each per
backend: `photometric_kernels`, `depth_loss_kernels`); `last_screen` is render_vjp's
densification side channel.

Forward reuse in render_vjp (documented contract): on CPU devices (PoCL) render_vjp reuses the
device state of the last forward of this backend when the camera, background, near, opacity
override and DropGaussian mask are equal AND every input array is byte-identical to what that
forward uploaded (compared against the zero-copy mapped input buffers, ~1-3 ms for SH3 at 100k).
A stage-method call or a render in between replaces that state; render_vjp itself leaves it
intact. On GPUs the forward is always recomputed: the kernels are cheaper than reading the inputs
back to verify them. Either way the result is the VJP at exactly the given inputs (an in-place
edit of an input is detected).

Device time per stage: after each call, `last_profile` maps stage name -> milliseconds on the
device timeline (profiling events of the in-order queue): a single-kernel stage's own duration, or
for a multi-command stage (the sorts, the scan, rasterize) the time from the end of the previous
stage to its last command's end. `last_stats` holds the counts (visible, intersections) of the
last forward.

Frame slots: a frame's buffers (projection outputs, bins and the tile sorter's ping-pong pair, the
rasterizer's images and packed records, the backward's v_proj) belong to one of two slots. Every
call renders into slot 0, except `forward_device(..., keep=True)`, which renders into slot 1, the
kept frame: only the next forward with keep=True overwrites it, so the virtual view of the
view_warp term (reings/train.py) is rendered once, read after the training view's forward and
backpropagated after its backward. The slots share the gradient outputs of a backward and its
per-intersection records; slot 1's buffers are allocated on its first use. A slot's current frame
is the only one of it that `backward_device` accepts.

Depth orders (docs/perf_notes.md §9; reings/backends/opencl/depth_order.py): the depth key is z
only (t_z's bits where t_z > near), so the sorted (keys, gid_from_rank) depend on the means, the
camera's z row, near and N alone. They live in one of three orders shared by the slots (not in the
slot's key buffers, which every projection rewrites): `forward_device(..., order_key=k)` binds the
frame to the order sorted under an equal key instead of sorting (`depth_order` "share": the
argument, else $REINGS_DEPTH_ORDER, else "share"; "sort": every forward sorts). An order is
re-sorted only when no live frame (a slot's current one) holds it; a backward checks that its
frame's order was not. V (ctrl[0]) counts the ranked Gaussians (a z key), the launch bound of
bin_emit and the reduces; the ones culled otherwise have no tile, so K, the emit slots, the images
and the gradients are those of a visible-only sort. The "visible" statistic (`visible`,
`last_stats`) stays the visible count (radii > 0): ctrl[2], summed by bin_count. `depth_sorts`
counts the forwards that sorted and that shared.

Memory: every device buffer comes from `Scratch` (persistent, per index space, grown by >= 1.5x),
so steady-state calls allocate nothing. Per Gaussian the depth sort takes each slot's key pair
(8 B), one sorter's scratch pair (8 B) and the three orders (24 B). Sync-free, the intersection
buffers hold N * n_tiles entries (93 bytes per entry over both slots: bin_counts.isect_bound_bytes).

Not here: input validation (reings/rendering.py), kernel math (kernels/*.cl), sorting/scan
(sort.py), rasterization (rasterize.py).
"""
from __future__ import annotations

import os
import warnings
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ...types import FIELDS, Camera, Gaussians, RenderOutput
from ..base import (CLAMP_GUARD, V_RECORD, Bins, Projected, RasterGrads, RasterOut, bin_problem, bins_problem,
                    grad_columns, projected_shape_problem, tile_grid)
from ..reference_drop import Drop, drop_args
from . import quirks
from .bin_counts import (CTRL_ISECTS, CTRL_RANKED, CTRL_VISIBLE, CTRL_WORDS, CountsRing, DeviceCounts,
                         bin_budget_setting, bin_mode_setting, choose_binning, isect_capacity)
from .depth_order import DepthOrders, depth_order_setting
from .device import open_device
from .program import library_for, typed_invoker
from .scratch import Scratch
from .sort import ExclusiveScan, RadixSort

CAM_RECORD = 24  # floats, layout in kernels/project.cl
CAM_CACHE = 256  # camera record buffers kept (OpenCLBackend._camera_buffer)
DEPTH_KEY_CULLED = 0xFFFFFFFF
GRAD_BITS = {"means": 1, "quats": 2, "log_scales": 4, "opacity_logits": 8, "sh": 16}
ISECT_GUESS = 8  # sync-free binning: intersections per Gaussian guessed before a slot's first K is known
ISECT_HISTORY = 8  # ... then the largest of its last ISECT_HISTORY known K's, plus 1/8
# tile_ranges' positions per work-item on CPU devices (kernels/bin.cl TR_CHUNK): 0.50-0.61x of one per work-item on
# fern's fine state, 2 Xeon cores (docs/perf_notes.md §43); GPUs 1
TR_CHUNK_CPU = 32
_F32, _I32, _U32 = np.float32, np.int32, np.uint32


def _sh_args(inp: dict, k: int) -> tuple:
    """project.cl's SH arguments (sh_dc, dc_stride, sh_rest, rest_stride, rest_offset; its sh_in_t) for
    the inputs `inp` at k coefficients: a packed [N,k,3] "sh" buffer, or, with "sh_rest" (the device
    trainer: its sh_dc [N,1,3] and sh_rest [N,kmax-1,3] parameter buffers read in place), the two
    buffers with "sh_rest_stride" floats per sh_rest row."""
    if "sh_rest" in inp:
        return inp["sh"], _I32(3), inp["sh_rest"], _I32(inp["sh_rest_stride"]), _I32(0)
    return inp["sh"], _I32(3 * k), inp["sh"], _I32(3 * k), _I32(3)


def proj_lanes(device) -> int:
    """project.cl's lanes on a CPU (PROJ_VW): 16 on PoCL's CPUs (whose builds take clang's builtins,
    quirks.clang_builtins: there 16 lanes move their rows as blocks, PROJ_BLOCK_IO), else 16 where the
    device's native float vector is 16 wide or more, else 8. Every lane computes its Gaussian's values
    with the same operations at either width: the same bytes
    (tests/test_project.py::test_project_widths_keep_the_bits). On a 2-core AVX-512 Xeon (PoCL 3.0) 16
    lanes took 0.87-0.94 of 8 lanes' project_fwd time on fern's fine state (docs/perf_notes.md §31); on
    2 AVX2 cores (AMD EPYC, Zen 3), where 8 lanes gather their rows a float at a time and write the
    rasterizer's records lane by lane, 16 lanes took 0.59-0.65 of project_fwd's and 0.80-0.85 of
    project_bwd's time on fern's fine and final states (docs/perf_notes.md §44)."""
    from .rasterize import native_lanes

    return 16 if quirks.clang_builtins(device) else native_lanes(device)


def tile_bits(n_tiles: int) -> int:
    """ceil(log2(n_tiles)): the bits of a tile id (0 for a single tile)."""
    return int(max(n_tiles - 1, 0)).bit_length()


def camera_record(cam: Camera, near: float) -> np.ndarray:
    """The float32 [CAM_RECORD] camera record of kernels/project.cl, computed in float64."""
    V = cam.viewmat
    W, H = cam.width, cam.height
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    tan_fovx, tan_fovy = 0.5 * W / fx, 0.5 * H / fy
    rec = np.zeros(CAM_RECORD, np.float64)
    rec[0:9] = V[:3, :3].ravel()
    rec[9:12] = V[:3, 3]
    rec[12:16] = (fx, fy, cx, cy)
    rec[16:19] = cam.center
    rec[19] = near
    rec[20] = (W - cx) / fx + CLAMP_GUARD * tan_fovx  # lim_x_pos
    rec[21] = cx / fx + CLAMP_GUARD * tan_fovx  # lim_x_neg
    rec[22] = (H - cy) / fy + CLAMP_GUARD * tan_fovy
    rec[23] = cy / fy + CLAMP_GUARD * tan_fovy
    return rec.astype(_F32)


def _frame_key(cam: Camera, background, near: float, override, drop: Drop | None = None) -> tuple:
    """Everything besides the Gaussians that a forward depends on (forward reuse in render_vjp)."""
    return (cam.K.tobytes(), cam.viewmat.tobytes(), cam.width, cam.height,
            tuple(float(x) for x in background), float(near), None if override is None else float(override),
            drop)


@dataclass
class _Frame:
    """Device state of one forward (buffers are its frame slot's; valid until the next call that
    renders into that slot: module docstring, "Frame slots")."""

    n: int
    width: int
    height: int
    tiles_x: int
    n_tiles: int
    sh_k: int
    counts: Any = (0, 0)  # (visible, K), or a DeviceCounts of a sync-free forward (resolved when asked)
    ranks: int = 0  # V, the ranked Gaussians (a z key; sync: read back, the launch bound of emit / reduces)
    cap: int = 0  # the K-sized buffers' capacity: K (sync) or the bound N * n_tiles (sync-free)
    sync_free: bool = False  # V and K live in bufs["ctrl"] (ctrl[0], ctrl[1]); the host never waited
    bufs: dict = field(default_factory=dict)
    key: tuple | None = None  # (camera, background, near, override, drop) for forward reuse
    camera: Camera | None = None  # the camera rendered
    drop: Drop | None = None  # DropGaussian's mask of the projection (its backward uses the same)
    packed: bool = False  # project_fwd wrote the rasterizer's records (no rasterize_prep launch)
    slot: int = 0  # the frame slot owning its buffers (module docstring): 0, or 1 for a kept frame
    order: Any = None  # the depth_order.Order its (keys, gid_from_rank) are in (None: uploaded bins)
    order_gen: int = 0  # that order's generation at the forward (module docstring, "Depth orders")

    @property
    def visible(self) -> int:
        """The visible Gaussians, radii > 0 (a sync-free frame's: read back when first asked)."""
        return self.resolved()[0]

    @property
    def isects(self) -> int:
        """K, the intersections (a sync-free frame's: read back when first asked)."""
        return self.resolved()[1]

    def resolved(self) -> tuple[int, int]:
        c = self.counts
        return c.get() if isinstance(c, DeviceCounts) else c


# project_fwd's per-Gaussian outputs (name, bytes per row): OpenCLBackend._proj_buffers
_PROJ_BUFFERS = (("means2d", 8), ("conics", 12), ("depths", 4), ("radii", 4), ("tile_rect", 16), ("colors", 12),
                 ("opacities", 4), ("depth_keys", 4), ("gid_vals", 4))


@dataclass
class _Slot:
    """The buffers of one frame slot (module docstring): the scratch names, the tile sorter (a
    sorted result may lie in its own ping-pong pair), the rasterizer (the images) and its current
    frame (the live one: its depth order is not re-sorted)."""

    mem: Any  # the backend's Scratch (slot 0) or its suffixed view (slot 1)
    tile_sorter: RadixSort
    raster: Any = None  # Rasterizer, built on first use (OpenCLBackend._raster)
    isects: deque = field(default_factory=lambda: deque(maxlen=ISECT_HISTORY))  # its last known K's
    frame: Any = None  # the last frame made in this slot (_new_frame)
    proj: Any = None  # (n, the scratch's allocation count, the projection's buffers): _proj_buffers


def opacity_only_fields(grad_fields) -> bool:
    """True when a backward wants the opacities' gradient alone (grad_fields == ("opacity_logits",):
    the soft depth term's and the DTU background pass's backward): the rasterizer's backward then sums
    only that record field (RASTER_BWD_OPACITY, the same bits for it; docs/perf_notes.md §11)."""
    return grad_fields is not None and set(grad_fields) == {"opacity_logits"}


class OpenCLBackend:
    """One OpenCL device (see the module docstring)."""

    engines = ("device", "host")  # Backend.engines: the device trainer by default

    def __init__(self, device_spec: str = "pocl", bin_mode: str | None = None, bin_budget: float | None = None,
                 depth_order: str | None = None):
        self.spec = device_spec
        self.bin_mode = bin_mode_setting(bin_mode)  # "auto" | "sync" | "async" (module docstring, "Binning")
        self.depth_order = depth_order_setting(depth_order)  # "share" | "sort" ("Depth orders")
        self.bin_budget = bin_budget_setting(bin_budget)  # auto's share of the device memory
        self.handle = open_device(device_spec)
        self.name = f"opencl:{device_spec}"
        self.device_name = self.handle.name
        self.cpu = quirks.is_cpu(self.handle.device)
        self.global_mem = int(self.handle.device.global_mem_size)  # CL_DEVICE_GLOBAL_MEM_SIZE (`binning`)
        self.queue = self.handle.queue
        self.lib = library_for(self.handle)
        self.scratch = Scratch(self.handle)
        self._slots: list[_Slot] = [self._new_slot(self.scratch)]  # slot 1 (kept frames) on first use
        with warnings.catch_warnings():  # re-retrieves the slot's sorter kernels, once
            warnings.simplefilter("ignore")
            self._depth_sorter = RadixSort(self.handle)  # sorts into an order: its scratch is only a sort's
            self._depth_sorter.warm(False)
        self._orders = DepthOrders(self.scratch)  # the sorted depth orders ("Depth orders")
        self.depth_sorts = {"sorted": 0, "shared": 0}  # forwards that sorted / that shared an order
        self.scan = ExclusiveScan(self.handle)
        self.wg = 256 if self.cpu else 128  # PoCL: fewer, larger work-groups (dispatch cost ~us each)
        self.tr_chunk = TR_CHUNK_CPU if self.cpu else 1  # tile_ranges' positions per work-item (kernels/bin.cl TR_CHUNK)
        self.proj_vw = proj_lanes(self.handle.device) if self.cpu else 1  # Gaussians per work-item in project.cl
        self.proj_wg = 512 // self.proj_vw if self.cpu else 128  # project.cl work-group (512 Gaussians on CPUs)
        # project.cl's SH rows through local memory on the GPU schedule only (_proj_defines, width-1 lanes);
        # REINGS_PROJ_STAGE=0|1, read when the backend is made
        stage = os.environ.get("REINGS_PROJ_STAGE", "")
        if stage not in ("", "0", "1"):
            raise ValueError(f"REINGS_PROJ_STAGE must be 0 or 1, got {stage!r}")
        self.proj_stage = not self.cpu if stage == "" else stage == "1"
        # project.cl's 16-lane work-items move their rows as blocks (PROJ_BLOCK_IO, the same bytes; docs/perf_notes.md
        # §32): None leaves it to the kernel (on where clang's shuffles exist), True / False force it (tests, A/Bs)
        self.proj_block: bool | None = None
        # an opacity-only backward through project_bwd_opacity (the same bytes as project_bwd with grad_mask 8,
        # without its projection: `_project_bwd_device`); False: project_bwd (tests, A/Bs)
        self.proj_bwd_opacity = True
        self.local_mem = int(self.handle.device.local_mem_size)
        self.fp64 = "cl_khr_fp64" in self.handle.device.extensions  # project_bwd's statistics (densify.h)
        self._kernels: dict = {}
        self._frame: _Frame | None = None
        self._keep: list = []  # host arrays referenced by non-blocking copies still in flight
        self._cams: dict = {}  # (K, viewmat, W, H, near) bytes -> read-only camera record buffer
        self._counts = np.empty(CTRL_WORDS, _U32)  # the binning's ctrl readback words (V, K, visible)
        self._ring: CountsRing | None = None  # the sync-free binning's pinned count words, on first use
        self.binned = {"sync": 0, "async": 0}  # forwards binned in each mode
        self._events: list = []  # (stage, event) of the current call
        self.last_profile: dict[str, float] = {}
        self._last_counts: Any = None  # the last forward's (visible, K) or DeviceCounts (last_stats)
        self.last_screen = None  # Backend.last_screen: (v_means2d, radii) of the last full render_vjp
        self._photometric = self._depth_loss = self._view_warp = None  # the loss kernels, built on first use
        self._block_mean = None  # the block mean's kernels (the view_warp term at 1/s), built on first use
        self._pending_o = None  # (frame, v_depth_opacity buffer) whose opacity-only records r.v_emit_o holds

    @property
    def last_stats(self) -> dict[str, int]:
        """The counts of the last forward, {"visible": radii > 0, "intersections": K} ({} before
        any); a sync-free forward's are read back when asked (a wait only if the queue has not
        passed them)."""
        c = self._last_counts
        if c is None:
            return {}
        v, k = c.get() if isinstance(c, DeviceCounts) else c
        return dict(visible=v, intersections=k)

    def binning(self, n: int, n_tiles: int) -> str:
        """"sync" or "async": how a forward of n Gaussians over n_tiles tiles bins under this
        backend's `bin_mode` (bin_counts.choose_binning; module docstring, "Binning")."""
        return choose_binning(self.bin_mode, self.cpu, isect_capacity(n, n_tiles), self.scratch.max_alloc,
                              self.global_mem, self.bin_budget)

    # ------------------------------------------------------------------------------------------
    # plumbing
    # ------------------------------------------------------------------------------------------
    def kernel(self, filename: str, name: str, **defines):
        # sorted only when there is an order to lose (a launch's host time: docs/perf_notes.md §25)
        key = (filename, name, tuple(sorted(defines.items())) if len(defines) > 1 else tuple(defines.items()))
        k = self._kernels.get(key)
        if k is None:
            k = self._kernels[key] = self.lib.get(filename, name, **defines)
        return k

    def launch(self, k, n: int, *args, wg: int | None = None):
        """Enqueue kernel `k` (from `kernel`) with one work-item per index in [0, n), the global size
        rounded up to the work-group size `wg` (default: the backend's), through the typed
        invoker (`typed_invoker`); the args are numpy scalars of the kernel's types and buffers.
        Returns the event, or None for n <= 0 (nothing enqueued). The device trainer launches its
        per-Gaussian kernels through this."""
        if n <= 0:
            return None
        wg = wg or self.wg
        gsize = -(-n // wg) * wg
        if not getattr(k, "_reings_typed", False):
            typed_invoker(k, args)
        return k(self.queue, (gsize,), (wg,), *args)

    @staticmethod
    def _nbytes(buf) -> int:
        """buf.size (a driver query through pyopencl, ~1 us), remembered on the buffer object itself
        (a buffer's size never changes; nothing here keeps a buffer alive)."""
        n = getattr(buf, "_reings_nbytes", None)
        if n is None:
            n = int(buf.size)
            try:
                buf._reings_nbytes = n
            except AttributeError:  # an object that takes no attributes: asked each time
                pass
        return n

    def _mark(self, stage: str, ev, span: bool = False):
        """Record the last event of a stage. span=True: the stage enqueued several commands and only
        the last event is known, so its time is measured from the end of the previous stage. Nothing
        is recorded on a queue without profiling timestamps (there is nothing to read from them)."""
        if ev is not None and self.handle.profiling:
            self._events.append((stage, ev, span))

    def pending_events(self) -> list:
        """(stage, event, span) of every stage recorded since the last `collect_profile` (what the
        next one will fold into `last_profile`)."""
        return list(self._events)

    def collect_profile(self) -> None:
        """Set `last_profile` to the stage times (ms) of the commands recorded since the last call,
        from their profiling events (the queue must have passed them): end - start of a
        single-kernel stage; end(stage) - end(previous stage) for a multi-command (span) stage.
        Called by every host-facing method after its final wait, and by the device trainer's
        `finish`."""
        prof: dict[str, float] = {}
        prev = None
        if not self.handle.profiling:  # no timestamps to read (device.queue_profiling)
            self._events = []
        for stage, ev, span in self._events:
            try:
                start, end = ev.profile.start, ev.profile.end
            except Exception:  # profiling off or unsupported: leave it out
                continue
            base = prev if (span and prev is not None) else start
            prof[stage] = prof.get(stage, 0.0) + max(end - base, 0) * 1e-6
            prev = end
        self.last_profile = prof
        self._events = []

    def _new_slot(self, mem) -> _Slot:
        with warnings.catch_warnings():  # a later sorter re-retrieves the same kernels, once
            warnings.simplefilter("ignore")
            sorter = RadixSort(self.handle)  # owns its ping-pong scratch
            sorter.warm(False)
        return _Slot(mem, sorter)

    def _slot(self, i: int) -> _Slot:
        """Frame slot `i` (0, or 1: the kept frame's buffers, names suffixed "@kept")."""
        if i >= len(self._slots):
            self._slots.append(self._new_slot(self.scratch.suffixed("@kept")))
        return self._slots[i]

    def _raster(self, fr: _Frame):
        """The rasterizer of the frame's slot (its images and packed records are the slot's; the
        backward's per-emit records are shared)."""
        return self._slot_raster(fr.slot)

    def _slot_raster(self, i: int):
        """The rasterizer of frame slot `i` (`_raster`), made on first use."""
        sl = self._slot(i)
        if sl.raster is None:
            from .rasterize import Rasterizer

            with warnings.catch_warnings():  # the second slot's re-retrieves the same kernels, once
                warnings.simplefilter("ignore")
                sl.raster = Rasterizer(self.handle, scratch=sl.mem, shared=self.scratch)
        return sl.raster

    def _upload(self, space: str, name: str, a: np.ndarray):
        a = np.ascontiguousarray(a)
        self._keep.append(a)
        return self.scratch.upload(space, name, a)

    def _read(self, buf, shape, dtype, wait_for=None) -> np.ndarray:
        """Enqueue a non-blocking read into a fresh host array (valid after _finish)."""
        import pyopencl as cl

        out = np.empty(shape, dtype)
        if out.size:
            cl.enqueue_copy(self.queue, out, buf, is_blocking=False, wait_for=wait_for)
        return out

    def _finish(self):
        self.queue.finish()
        self._keep = []
        self.collect_profile()

    # ------------------------------------------------------------------------------------------
    # forward pieces on the device
    # ------------------------------------------------------------------------------------------
    def _upload_gaussians(self, g: Gaussians) -> dict:
        return {f: self._upload("gauss", "in_" + f, getattr(g, f)) for f in FIELDS}

    def _project_device(self, fr: _Frame, inp: dict, cam: Camera, near: float, override,
                        drop: Drop | None = None) -> None:
        if drop is not None and override is not None:
            raise ValueError("project_fwd: a DropGaussian mask is never combined with an opacity override")
        n = fr.n
        fr.drop = drop
        b = fr.bufs
        b["cam"] = self._camera_buffer(cam, near)
        b.update(self._proj_buffers(self._slot(fr.slot), n))
        k = self.kernel("project.cl", "project_fwd", **self._proj_defines(fr.sh_k))
        ov = _F32(override if override is not None else 0.0)
        ev = self.launch(k, -(-n // self.proj_vw), _I32(n), inp["means"], inp["quats"], inp["log_scales"],
                          inp["opacity_logits"], *_sh_args(inp, fr.sh_k), b["cam"], _I32(fr.width), _I32(fr.height),
                          ov, *drop_args(drop), b["means2d"], b["conics"], b["depths"], b["radii"], b["tile_rect"],
                          b["colors"], b["opacities"], b["depth_keys"], b["gid_vals"], b["ctrl"],
                          self._raster(fr).packed_for(n), wg=self.proj_wg)
        fr.packed = True  # the rasterizer's records too: _raster_fwd launches no rasterize_prep
        self._mark("project_fwd", ev)

    def _proj_buffers(self, sl: _Slot, n: int) -> dict:
        """project_fwd's output buffers of n Gaussians in slot `sl` (_PROJ_BUFFERS, and the binning's
        control words: project_fwd zeroes ctrl[2]), looked up in the scratch once per n and kept until
        the scratch allocates again (a buffer found stays the one of its name until then)."""
        s = sl.mem
        c = sl.proj
        if c is None or c[0] != n or c[1] != s.allocations:
            bufs = {name: s.get("gauss", name, n, row) for name, row in _PROJ_BUFFERS}
            bufs["ctrl"] = s.get("small", "ctrl", CTRL_WORDS, 4)
            c = sl.proj = (n, s.allocations, bufs)
        return c[2]

    def _camera_buffer(self, cam: Camera, near: float):
        """The camera record of (cam, near) in its own read-only buffer, made once per distinct
        camera (at most CAM_CACHE kept; a training run has a few views): no upload per call."""
        import pyopencl as cl

        key = (cam.K.tobytes(), cam.viewmat.tobytes(), cam.width, cam.height, float(near))
        buf = self._cams.get(key)
        if buf is None:
            if len(self._cams) >= CAM_CACHE:
                self._cams.clear()  # frames still holding a buffer keep it alive
            mf = cl.mem_flags
            buf = self._cams[key] = cl.Buffer(self.handle.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                              hostbuf=camera_record(cam, near))
        return buf

    def _bin_device(self, fr: _Frame, allow_async: bool = True, order_key=None) -> None:
        """The depth order (`_depth_order`: sorted, or shared under `order_key`), counts, scan,
        then (V, K, visible): one blocking read (sync), or left in ctrl on the device (sync-free,
        when `binning` says so and allow_async), then emit, tile sort, tile ranges
        (`_bin_emit_ranges`)."""
        import pyopencl as cl

        sl = self._slot(fr.slot)
        n, s, b = fr.n, sl.mem, fr.bufs
        # (1) the depth order of all N: culled keys (0xFFFFFFFF) last, ties in gid order
        self._depth_order(fr, order_key)
        keys, gfr = b["depth_keys_sorted"], b["gid_from_rank"]
        # (2) tiles touched per rank, V, the visible count; exclusive scan -> offset_from_rank, K
        touched = s.get("gauss", "tiles_touched", n + 1, 4)
        ctrl = b["ctrl"]  # its visible count zeroed by project_fwd (or _upload_projected)
        offsets = b["offset_from_rank"] = s.get("gauss", "offset_from_rank", n + 1, 4)
        sc = self.scan  # bin_count writes the scan's block sums too: the scan is its scan_add alone
        nblocks, chunk, items, wg = sc.blocks(n + 1)
        sums = sc.block_sums(nblocks)
        ev = self.launch(self.kernel("bin.cl", "bin_count", **sc.defines), items, _I32(n), keys, gfr,
                         b["tile_rect"], b["radii"], touched, ctrl, _U32(chunk), sums, wg=wg)
        self._mark("bin_count", ev)
        ev = sc.add(touched, offsets, n + 1, sums, ctrl, CTRL_ISECTS)
        self._mark("scan", ev)
        if allow_async and self.binning(n, fr.n_tiles) == "async":
            # sync-free: buffers at the bound, the counts read back without blocking
            if self._ring is None:
                self._ring = CountsRing(self.handle)
            fr.sync_free, fr.cap = True, isect_capacity(n, fr.n_tiles)
            fr.counts = self._ring.read(ctrl, sl.isects)
        else:
            # the one blocking device -> host read of the forward: (V, K, visible) together
            counts = self._counts
            cl.enqueue_copy(self.queue, counts, ctrl, is_blocking=True)
            self._keep = []
            fr.ranks = int(counts[CTRL_RANKED])
            fr.counts = int(counts[CTRL_VISIBLE]), int(counts[CTRL_ISECTS])
            fr.cap = fr.counts[1]
            sl.isects.append(fr.cap)  # the launch estimates of later sync-free forwards, if any
        self.binned["async" if fr.sync_free else "sync"] += 1
        self._bin_emit_ranges(fr, sl)

    def _depth_order(self, fr: _Frame, order_key) -> None:
        """Bind the frame to its depth order (module docstring, "Depth orders"): with `order_key`
        (and `depth_order` "share"), the order sorted under the same tag (order_key, N, SH count)
        if one is kept; else a stable 32-bit sort of the projection's (depth_keys, gid_vals) into
        an order that no live frame holds."""
        tag = None if order_key is None or self.depth_order != "share" else (order_key, fr.n, fr.sh_k)
        o = self._orders.find(tag)
        if o is not None:
            self.depth_sorts["shared"] += 1
        else:
            held = [sl.frame.order for sl in self._slots if sl.frame is not None]
            o = self._orders.claim(held, fr.n)
            b = fr.bufs
            _, _, ev = self._depth_sorter.sort_pairs(b["depth_keys"], b["gid_vals"], fr.n, 0, 32,
                                                     out=(o.keys, o.gids))
            o.tag = tag  # shareable from now on (not if the sort had raised)
            self._mark("sort_depth", ev, span=True)
            self.depth_sorts["sorted"] += 1
        fr.order, fr.order_gen = o, o.gen
        fr.bufs["depth_keys_sorted"], fr.bufs["gid_from_rank"] = o.keys, o.gids

    def _isect_estimate(self, sl: _Slot, fr: _Frame) -> int:
        """The launch size's guess of a sync-free frame's K (kernels loop to the real one): the
        largest of the slot's last known K's plus 1/8, else ISECT_GUESS per Gaussian; at most the
        bound. Only reads that the queue has already passed are looked at (no wait)."""
        self._ring.poll()
        guess = max(sl.isects) if sl.isects else ISECT_GUESS * fr.n
        return min(fr.cap, guess + guess // 8 + 1)

    def _bin_emit_ranges(self, fr: _Frame, sl: _Slot) -> None:
        """bin_emit, the stable tile sort, tile_ranges: with host counts (V, K), or sync-free with
        the counts of ctrl (count_at 0: V, 1: K), launched over N ranks and an estimate of K."""
        n, s, b, cap, ctrl = fr.n, sl.mem, fr.bufs, fr.cap, fr.bufs["ctrl"]
        if fr.sync_free:
            v_launch, at_v, at_k = n, _I32(CTRL_RANKED), _I32(CTRL_ISECTS)
            k_launch = self._isect_estimate(sl, fr)
        else:
            v_launch, at_v, at_k = fr.ranks, _I32(-1), _I32(-1)
            k_launch = cap
        gfr, offsets = b["gid_from_rank"], b["offset_from_rank"]
        # (3) emit: tile ids row-major per rank at its slots; values = emit slot
        tile_keys = s.get("isect", "tile_keys", cap, 4)
        emit_vals = s.get("isect", "emit_vals", cap, 4)
        gid_from_emit = b["gid_from_emit"] = s.get("isect", "gid_from_emit", cap, 4)
        ev = self.launch(self._bin_kernel("bin_emit"), v_launch, _I32(v_launch), _I32(fr.tiles_x), gfr,
                          offsets, b["tile_rect"], tile_keys, emit_vals, gid_from_emit, ctrl, at_v)
        self._mark("bin_emit", ev)
        # (4) stable tile sort over ceil(log2 T) bits: keeps (depth, gid) order inside each tile
        tk, efi, ev = sl.tile_sorter.sort_pairs(tile_keys, emit_vals, cap, 0, tile_bits(fr.n_tiles),
                                                count=(ctrl, CTRL_ISECTS) if fr.sync_free else None,
                                                estimate=k_launch)
        self._mark("sort_tile", ev, span=True)
        b["tile_keys_sorted"], b["emit_from_isect"] = tk, efi
        # (5) tile ranges + gid_from_isect, no atomics
        ranges = b["tile_ranges"] = s.get("tile", "tile_ranges", fr.n_tiles, 8)
        gfi = b["gid_from_isect"] = s.get("isect", "gid_from_isect", cap, 4)
        ev = self.launch(self._bin_kernel("tile_ranges"), -(-(k_launch + 1) // self.tr_chunk), _I32(cap),
                         _I32(fr.n_tiles), tk, efi, gid_from_emit, ranges, gfi, ctrl, at_k)
        self._mark("tile_ranges", ev)

    def _bin_kernel(self, name: str):
        """bin_emit / tile_ranges: bin.cl's program with TR_CHUNK (the one `prepare` builds)."""
        return self.kernel("bin.cl", name, TR_CHUNK=self.tr_chunk)

    def _rank_count(self, fr: _Frame) -> tuple:
        """(n_rank, count) of the per-rank reduces: (V, None), or sync-free (N, (ctrl, 0)); V the
        ranked Gaussians (the culled ones among them reduce empty ranges)."""
        return (fr.n, (fr.bufs["ctrl"], CTRL_RANKED)) if fr.sync_free else (fr.ranks, None)

    def _new_frame(self, n: int, width: int, height: int, sh_k: int, slot: int = 0) -> _Frame:
        """A frame in `slot`, which becomes the slot's current one (the previous one's buffers and
        its hold on its depth order are gone)."""
        if slot == 0:
            self._frame = None  # a call into slot 0 invalidates the previous forward's device state
        tiles_x, tiles_y = tile_grid(width, height)
        self._events = []
        fr = _Frame(n=n, width=width, height=height, tiles_x=tiles_x, n_tiles=tiles_x * tiles_y, sh_k=sh_k,
                    slot=slot)
        self._slot(slot).frame = fr
        return fr

    def _forward(self, g: Gaussians, cam: Camera, background, near: float, override,
                 want_importance: bool, drop: Drop | None = None) -> _Frame:
        fr = self._new_frame(len(g), cam.width, cam.height, g.sh.shape[1])
        fr.bufs["in"] = self._upload_gaussians(g)
        self._project_device(fr, fr.bufs["in"], cam, near, override, drop)
        self._bin_device(fr)
        self._raster_fwd(fr, background, want_importance)
        fr.key = _frame_key(cam, background, near, override, drop)
        return fr

    # ------------------------------------------------------------------------------------------
    # rasterizer adapter (reings/backends/opencl/rasterize.py owns the kernels)
    # ------------------------------------------------------------------------------------------
    def _raster_fwd(self, fr: _Frame, background, want_importance: bool) -> None:
        """rasterize_prep (unless project_fwd wrote the records: fr.packed) + rasterize_fwd; importance:
        per-emit records reduced per gid."""
        import pyopencl as cl

        r, b = self._raster(fr), fr.bufs
        ev = r.fwd(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], fr.n, b["tile_ranges"],
                   b["gid_from_isect"], b["emit_from_isect"], fr.cap, fr.width, fr.height,
                   background, importance=want_importance, prepared=fr.packed)
        self._mark("rasterize_fwd", ev, span=True)
        b["out_rgb"], b["out_depth"], b["out_alpha"], b["out_T"], b["out_last"] = r.pixel_buffers()
        if want_importance:
            imp = b["importance"] = self._slot(fr.slot).mem.get("gauss", "importance", fr.n, 4)
            if fr.n:  # culled rows are not written by the reduce: zero them all first
                cl.enqueue_fill_buffer(self.queue, imp, _F32(0), 0, 4 * fr.n)
            n_rank, count = self._rank_count(fr)
            ev = r.reduce(r.imp_emit, 1, b["offset_from_rank"], b["gid_from_rank"], n_rank, imp, count=count)
            self._mark("importance_reduce", ev)

    def _raster_bwd(self, fr: _Frame, v_rgb, v_depth, v_alpha, opacity_only: bool = False) -> None:
        """rasterize_bwd (per-emit records) + isect_reduce into v_proj [N, V_RECORD] (rows of
        culled gids are zero or left unwritten: project_bwd never reads them)."""
        vr = None if v_rgb is None else self._upload("pixel", "v_rgb", np.asarray(v_rgb, _F32))
        vd = None if v_depth is None else self._upload("pixel", "v_depth", np.asarray(v_depth, _F32))
        va = None if v_alpha is None else self._upload("pixel", "v_alpha", np.asarray(v_alpha, _F32))
        self._raster_bwd_buffers(fr, vr, vd, va, opacity_only)

    def _raster_bwd_buffers(self, fr: _Frame, vr, vd, va, opacity_only: bool = False, vdo=None) -> None:
        """_raster_bwd on cotangent images that are already device buffers (or None). Refuses a
        frame whose depth order was re-sorted since its forward (never, by construction: module
        docstring, "Depth orders"). opacity_only: the records carry d/d opacity only (the other
        fields 0; `opacity_only_fields`). vdo: a second depth cotangent whose opacity-only records
        go to r.v_emit_o (`backward_device(v_depth_opacity=)`)."""
        self._check_order(fr)
        self._pending_o = None  # a backward replaces or discards any held second records
        r, b = self._raster(fr), fr.bufs
        ev = r.bwd(b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], fr.cap, fr.width, fr.height,
                   vr, vd, va, opacity_only=opacity_only, v_depth_o=vdo)
        self._mark("rasterize_bwd", ev, span=True)
        self._reduce_records(fr, r.v_emit)

    def discard_held_records(self) -> None:
        """Forget the records an announced backward holds (`backward_device(v_depth_opacity=)`): the
        caller is about to rewrite the announced cotangent's buffer, whose identity is what the next
        backward matches."""
        self._pending_o = None

    def _check_order(self, fr: _Frame) -> None:
        if fr.order is not None and fr.order.gen != fr.order_gen:
            raise RuntimeError(f"backward: the frame's depth order ({fr.order.name}) was re-sorted since its "
                               "forward; a frame is backpropagated while it is its slot's current one")

    def _reduce_records(self, fr: _Frame, records) -> None:
        """isect_reduce of per-emit gradient records into the frame slot's v_proj [N, V_RECORD]."""
        r, b = self._raster(fr), fr.bufs
        vp = b["v_proj"] = self._slot(fr.slot).mem.get("gauss", "v_proj", fr.n, 4 * V_RECORD)
        n_rank, count = self._rank_count(fr)
        ev = r.reduce(records, V_RECORD, b["offset_from_rank"], b["gid_from_rank"], n_rank, vp, count=count)
        self._mark("isect_reduce", ev)

    # ------------------------------------------------------------------------------------------
    # device-resident entry points (the training engine, reings/backends/opencl/trainer.py)
    # ------------------------------------------------------------------------------------------
    def forward_device(self, inp: dict, n: int, sh_k: int, camera: Camera, background=(0.0, 0.0, 0.0),
                       near: float = 0.01, opacity_override: float | None = None,
                       drop: Drop | None = None, keep: bool = False, order_key=None,
                       importance: bool = False) -> _Frame:
        """`render`'s forward on Gaussians that already live on the device: `inp` maps each field of
        FIELDS to a buffer ([N,3] means, [N,4] quats, [N,3] log_scales, [N] opacity_logits,
        [N,sh_k,3] sh). Nothing is uploaded (the camera record buffer is cached per camera) and
        nothing is read back but the bin stage's (V, K) control words (sync-free: without a wait,
        fr.visible / fr.isects resolved when asked). The returned frame's buffers (fr.bufs["out_rgb"],
        "out_depth", "out_alpha", "out_T", "radii", ...) stay valid until the next call on this
        backend that renders into the frame's slot (module docstring): any call but a forward with
        keep=True for an ordinary frame, the next forward with keep=True for a kept one; the
        caller must keep `inp` unchanged until `backward_device` has run. drop: DropGaussian's mask
        (reference_drop.Drop, None: none); `backward_device` of the frame uses the same.
        order_key: None (sort), or a hashable promise that the depth order (the means, the camera's
        viewmat row 2 and near) is that of every earlier forward with an equal key: the frame then
        shares a kept order instead of sorting (module docstring, "Depth orders"; the device
        trainer's key: trainer.py). A wrong promise gives a wrong render, so keys must change
        with the means. importance: also the per-Gaussian alpha*T sums, fr.bufs["importance"] [N]
        float32 (as `render(want_importance=True)`)."""
        fr = self._new_frame(int(n), camera.width, camera.height, int(sh_k), 1 if keep else 0)
        fr.camera = camera
        fr.bufs["in"] = dict(inp)
        self._project_device(fr, fr.bufs["in"], camera, near, opacity_override, drop)
        self._bin_device(fr, order_key=order_key)
        self._raster_fwd(fr, background, importance)
        self._last_counts = fr.counts
        return fr

    def backward_device(self, fr: _Frame, v_rgb=None, v_depth=None, v_alpha=None,
                        opacity_override: float | None = None, grad_fields: Sequence[str] | None = None,
                        v_depth_opacity=None, out: dict | None = None, accumulate: bool = False,
                        stats: tuple | None = None) -> dict:
        """`render_vjp`'s backward for a frame of `forward_device`, with the cotangent images as
        device buffers ([H,W,3], [H,W], [H,W]; None = zero). Returns the gradient buffers
        {field: buffer} ([N,3], [N,4], [N,3], [N], [N,sh_k,3]; fields outside `grad_fields` are
        zeros), valid until the next backward on this backend. fr.bufs["v_proj"] [N, V_RECORD]
        (rows of culled gids zero or unwritten; the frame slot's, valid as long as the frame) and
        fr.bufs["radii"] feed the densification statistics.
        The frame's DropGaussian mask (fr.drop, from forward_device) applies. The frame must be its
        slot's current one (no forward into its slot since: RuntimeError otherwise).

        v_depth_opacity (a device buffer): announces the next backward of this frame, an opacity-only one
        (grad_fields == ("opacity_logits",)) of that depth cotangent alone; this backward's rasterize_bwd
        then also makes its records (RASTER_BWD_DEPTH_O, the same bits as its own pass), and that next
        call only reduces them: one rasterize_bwd fewer (docs/perf_notes.md §13). Any other backward in
        between discards them; a sync-free frame, or an opacity-only backward here, ignores it.

        out: {field: buffer} (every field of FIELDS, each at least the rows above) that project_bwd writes
        the gradients into instead of this backend's own buffers (returned, then: the device trainer's
        held gradients, so that the next backward leaves them alone with no copy). accumulate (with out):
        the gradients of the `grad_fields` are added into `out` (one float32 add per element, as
        reference_state.grad_add) and its other fields are left as they are.

        stats: None, or the densification statistics' buffers (accum [N] float32, count [N] int32,
        max_radii [N] float32) that this backward's screen-space gradients are added to, in
        project_bwd (densify.h: what kernels/densify_accumulate.cl adds, the same bits, with no
        launch of its own); not with an opacity-only backward (its records carry no mean gradient)."""
        if self._slot(fr.slot).frame is not fr:
            raise RuntimeError(f"backward_device: a later forward replaced the frame (slot {fr.slot})")
        if accumulate and out is None:
            raise ValueError("backward_device: accumulate needs the buffers to add into (out=)")
        if out is not None:  # before anything is enqueued or announced
            short = [f for f, cols in grad_columns(fr.sh_k).items() if f not in out or self._nbytes(out[f]) < 4 * cols * fr.n]
            if short:
                raise ValueError(f"backward_device: out= lacks room for {short} ({fr.n} rows, SH count {fr.sh_k})")
        only = opacity_only_fields(grad_fields)
        if stats is not None and only:
            raise ValueError("backward_device: stats= needs a backward of the mean gradients, not an opacity-only one")
        held, self._pending_o = self._pending_o, None
        if (held is not None and held[0] is fr and held[1] is v_depth and v_depth is not None and v_rgb is None
                and v_alpha is None and only):
            self._check_order(fr)  # the records announced by the previous backward: reduce them
            self._reduce_records(fr, self._raster(fr).v_emit_o)
            return self._project_bwd_device(fr, opacity_override, grad_fields, out, accumulate)
        fuse = v_depth_opacity is not None and not only and not fr.sync_free
        self._raster_bwd_buffers(fr, v_rgb, v_depth, v_alpha, only, v_depth_opacity if fuse else None)
        if fuse:
            self._pending_o = (fr, v_depth_opacity)
        return self._project_bwd_device(fr, opacity_override, grad_fields, out, accumulate, stats)

    # ------------------------------------------------------------------------------------------
    # training: the trainer factory and the loss kernels (reings/backends/opencl/losses.py)
    # ------------------------------------------------------------------------------------------
    def trainer(self, images, engine: str = "auto", adam: str = "auto", profile: dict | None = None):
        """Backend.trainer: "device" (the default) -> DeviceTrainer (reings/backends/opencl/trainer.py,
        the state resident on this device; `adam` its Adam location); "host" -> HostTrainer
        (reings/backends/host_trainer.py: numpy state, this backend's render / render_vjp and host
        losses)."""
        from ..base import select_engine

        if select_engine(self, engine) == "host":
            from ..host_trainer import HostTrainer

            return HostTrainer(self, images, profile=profile)
        from .trainer import DeviceTrainer

        return DeviceTrainer(self, images, adam=adam, profile=profile)

    def prepare(self, sh_ks=(), importance: bool = False, opacity_only: bool = False, soft_shared: bool = False,
                depth_loss: bool = False, view_warp: bool = False, photometric: bool = False,
                block_mean: bool = False) -> None:
        """Build now the programs that forwards and backwards with these options will use; each is
        otherwise built on first use. project.cl at each SH coefficient count in `sh_ks`, bin.cl, the
        rasterizer and the variants asked for: the importance forward, the opacity-only backward, and
        for `soft_shared` (the soft depth term on the photometric render: `backward_device`'s fused
        second cotangent on a sync-binned frame, an opacity-only backward on a sync-free one) the
        variants this backend's binning mode may take; the depth loss's, view_warp's, the block mean's
        (the view_warp term at 1/s) and the photometric loss's kernels. The sorts, the scan and the device trainer's own kernels are built when their
        owners are made. `train.fit` calls it (with `train.programs_of`) before a fit's clock starts:
        on a fresh machine NVIDIA's compiler takes ~0.1-0.9 s a program (metrics.json `kernel_builds`;
        docs/results.md §38)."""
        for k in sorted(set(int(k) for k in sh_ks)):
            self.lib.program("project.cl", **self._proj_defines(k))
        self.lib.program("bin.cl", **self.scan.defines)
        self.lib.program("bin.cl", TR_CHUNK=self.tr_chunk)  # bin_emit and tile_ranges (one program)
        sync_free = soft_shared and self.bin_mode != "sync"  # "auto" may bin a forward sync-free
        self._slot_raster(0).prepare(importance=importance, opacity_only=opacity_only or sync_free,
                                     depth_o=soft_shared and self.bin_mode != "async")
        if depth_loss:
            self.depth_loss_kernels
        if view_warp:
            self.view_warp_kernels
        if block_mean:
            self.block_mean_kernels
        if photometric:
            self.photometric_kernels

    @property
    def photometric_kernels(self):
        """This device's PhotometricCL (kernels/photometric.cl), built on first use."""
        if self._photometric is None:
            from .losses import PhotometricCL

            self._photometric = PhotometricCL(self.handle)
        return self._photometric

    @property
    def depth_loss_kernels(self):
        """This device's DepthLossCL (kernels/depth_loss.cl, depth_smooth fused in), built on first use."""
        if self._depth_loss is None:
            from .losses import DepthLossCL

            self._depth_loss = DepthLossCL(self.handle)
        return self._depth_loss

    @property
    def view_warp_kernels(self):
        """This device's ViewWarpCL (kernels/view_warp.cl), built on first use."""
        if self._view_warp is None:
            from .view_warp import ViewWarpCL

            self._view_warp = ViewWarpCL(self.handle)
        return self._view_warp

    @property
    def block_mean_kernels(self):
        """This device's BlockMeanCL (kernels/block_mean.cl), built on first use."""
        if self._block_mean is None:
            from .block_mean import BlockMeanCL

            self._block_mean = BlockMeanCL(self.handle, wg=self.wg)
        return self._block_mean

    def view_warp(self, virt, depth, gt, fx: float, baseline: float, weight: float, smooth_weight: float):
        """Backend.view_warp on this device (host arrays uploaded, the cotangents read back)."""
        vw = self.view_warp_kernels
        _, v_virt, v_depth = vw(virt, depth, gt, fx, baseline, weight, smooth_weight)
        st = vw.read_stats()
        return {"loss": st["loss"], "valid_fraction": st["valid_fraction"]}, v_virt, v_depth

    def photometric_loss(self, rgb: np.ndarray, gt: np.ndarray, w_l1: float, w_ssim: float):
        """Backend.photometric_loss on this device (host arrays uploaded, dL/d rgb read back)."""
        return self.photometric_kernels(rgb, gt, w_l1, w_ssim)

    def depth_loss(self, depth: np.ndarray, target: np.ndarray, p_local: int, p_global: int, margin: float,
                   w_local: float = 0.1, w_global: float = 1.0, smooth=None, weight=None):
        """Backend.depth_loss on this device (host arrays uploaded, dL/d depth read back)."""
        return self.depth_loss_kernels(depth, target, p_local, p_global, margin, w_local, w_global, smooth, weight)

    # ------------------------------------------------------------------------------------------
    # fused paths
    # ------------------------------------------------------------------------------------------
    def render(self, gaussians: Gaussians, camera: Camera, background: Sequence[float] = (0, 0, 0),
               near: float = 0.01, opacity_override: float | None = None,
               want_importance: bool = False, drop: Drop | None = None) -> RenderOutput:
        fr = self._forward(gaussians, camera, background, near, opacity_override, want_importance, drop)
        b = fr.bufs
        H, W = camera.height, camera.width
        rgb = self._read(b["out_rgb"], (H, W, 3), _F32)
        depth = self._read(b["out_depth"], (H, W), _F32)
        alpha = self._read(b["out_alpha"], (H, W), _F32)
        final_T = self._read(b["out_T"], (H, W), _F32)
        imp = self._read(b["importance"], (fr.n,), _F32) if want_importance else None
        self._finish()
        self._last_counts = fr.counts
        stats = self.last_stats
        self._frame = fr
        return RenderOutput(rgb=rgb, depth=depth, alpha=alpha, final_T=final_T, importance=imp, stats=stats)

    def render_frames(self, gaussians: Gaussians, cameras, background: Sequence[float] = (0, 0, 0),
                      near: float = 0.01, depth: bool = False):
        """`render` of many cameras: the Gaussians are uploaded once; only rgb (and depth) are read."""
        inp = None
        for cam in cameras:
            fr = self._new_frame(len(gaussians), cam.width, cam.height, gaussians.sh.shape[1])
            if inp is None:
                inp = self._upload_gaussians(gaussians)
            fr.bufs["in"] = inp
            self._project_device(fr, inp, cam, near, None)
            self._bin_device(fr)
            self._raster_fwd(fr, background, False)
            H, W = cam.height, cam.width
            rgb = self._read(fr.bufs["out_rgb"], (H, W, 3), _F32)
            d = self._read(fr.bufs["out_depth"], (H, W), _F32) if depth else None
            self._finish()
            yield rgb, d

    def _reusable(self, g: Gaussians, key: tuple) -> _Frame | None:
        """The previous forward, if it was computed on exactly these inputs (CPU devices only)."""
        fr = self._frame
        if fr is None or not self.cpu or fr.key != key or fr.n != len(g) or fr.sh_k != g.sh.shape[1]:
            return None
        for f in FIELDS:
            a = np.ascontiguousarray(getattr(g, f))
            with self.scratch.mapped(fr.bufs["in"][f], a.shape, a.dtype) as m:
                if not np.array_equal(m.view(_U32), a.view(_U32)):
                    return None
        return fr

    def render_vjp(self, gaussians: Gaussians, camera: Camera, v_rgb: np.ndarray,
                   v_depth: np.ndarray | None = None, v_alpha: np.ndarray | None = None,
                   background: Sequence[float] = (0, 0, 0), near: float = 0.01,
                   opacity_override: float | None = None,
                   grad_fields: Sequence[str] | None = None, drop: Drop | None = None) -> Gaussians:
        g = gaussians
        fr = self._reusable(g, _frame_key(camera, background, near, opacity_override, drop))
        self._events = []
        if fr is None:
            fr = self._forward(g, camera, background, near, opacity_override, False, drop)
        self._frame = fr  # the backward leaves the forward's buffers intact: a second VJP may reuse it
        self._raster_bwd(fr, v_rgb, v_depth, v_alpha, opacity_only_fields(grad_fields))
        out = self._project_bwd_device(fr, opacity_override, grad_fields)
        n, k = fr.n, fr.sh_k
        res = {f: self._read(out[f], shp, _F32) for f, shp in
               (("means", (n, 3)), ("quats", (n, 4)), ("log_scales", (n, 3)), ("opacity_logits", (n,)),
                ("sh", (n, k, 3)))}
        screen = None
        if grad_fields is None:  # the photometric pass: densification needs dL/d means2d and radii
            screen = (self._read(fr.bufs["v_proj"], (n, V_RECORD), _F32), self._read(fr.bufs["radii"], (n,), _I32))
        self._finish()
        if screen is not None:
            v_proj, radii = screen
            # isect_reduce leaves the rows of culled Gaussians untouched: zero them
            self.last_screen = (np.where(radii[:, None] > 0, v_proj[:, :2], 0).astype(np.float32), radii)
        else:
            self.last_screen = None
        self._last_counts = fr.counts
        return Gaussians(**res)

    def _stats_args(self, fr: _Frame, stats: tuple | None) -> tuple:
        """project_bwd's last arguments: (stats flag, W/2, H/2 in densify.h's type, accum, count,
        max_radii); without stats the flag is 0 and the radii buffer stands in (never accessed)."""
        real = np.float64 if self.fp64 else _F32
        if stats is None:
            r = fr.bufs["radii"]
            return _I32(0), real(0), real(0), r, r, r
        return (_I32(1), real(0.5 * fr.width), real(0.5 * fr.height), *stats)

    def _proj_defines(self, sh_k: int) -> dict:
        """project.cl's build defines at sh_k coefficients: the GPU schedule stages SH rows through
        local memory when there is more than one coefficient (PROJ_SH_STAGE, a work-group of
        proj_wg Gaussians; the same bits; docs/perf_notes.md §15), unless REINGS_PROJ_STAGE=0 or
        the device's local memory is too small. DENSIFY_FP64: project_bwd's densification statistics
        in double where the device has it (as the device trainer builds densify_accumulate.cl).
        PROJ_BLOCK_IO only where `proj_block` forces it (the kernel's default: on at 16 lanes with clang)."""
        d = dict(SH_K=sh_k, PROJ_VW=self.proj_vw, DENSIFY_FP64=int(self.fp64))
        if self.proj_block is not None:
            if self.proj_block and self.proj_vw != 16:
                raise ValueError(f"project.cl's PROJ_BLOCK_IO needs 16 lanes (proj_vw), got {self.proj_vw}")
            d["PROJ_BLOCK_IO"] = int(self.proj_block)
        if self.proj_stage and self.proj_vw == 1 and sh_k > 1 and self.proj_wg * ((3 * sh_k) | 1) * 4 <= self.local_mem:
            d.update(PROJ_SH_STAGE=1, PROJ_WG=self.proj_wg)
        return d

    def _project_bwd_device(self, fr: _Frame, override, grad_fields, out: dict | None = None,
                            accumulate: bool = False, stats: tuple | None = None) -> dict:
        """project_bwd into `out` (default: this backend's gradient buffers); accumulate: added into
        `out`'s rows, the fields outside `grad_fields` left untouched (project.cl GRAD_F); stats:
        (accum, count, max_radii) buffers the densification statistics are added to (densify.h;
        otherwise the radii buffer stands in for them, never touched). An opacity-only backward
        (`opacity_only_fields`, no stats) runs project_bwd_opacity instead where `proj_bwd_opacity`
        (the same bytes in every output: the frame's radii from its project_fwd decide the culling, no
        projection: ~0.1-0.3 ms against project_bwd's ~1.3-3 ms at 52k Gaussians on 2 PoCL cores)."""
        n, s, b = fr.n, self.scratch, fr.bufs
        mask = 0
        for f in (FIELDS if grad_fields is None else grad_fields):
            mask |= GRAD_BITS[f]
        if out is None:  # else backward_device has checked the caller's buffers
            out = {f: s.get("gauss", f"v_{f}", n, 4 * cols) for f, cols in grad_columns(fr.sh_k).items()}
        inp = b["in"]
        if stats is None and self.proj_bwd_opacity and opacity_only_fields(grad_fields):
            k = self.kernel("project.cl", "project_bwd_opacity", **self._proj_defines(fr.sh_k))
            ev = self.launch(k, -(-n // self.proj_vw), _I32(n), inp["opacity_logits"],
                             _F32(override if override is not None else 0.0), drop_args(fr.drop)[2],
                             _I32(1 if accumulate else 0), b["radii"], b["v_proj"], out["means"], out["quats"],
                             out["log_scales"], out["opacity_logits"], out["sh"], wg=self.proj_wg)
            self._mark("project_bwd_opacity", ev)
            return out
        k = self.kernel("project.cl", "project_bwd", **self._proj_defines(fr.sh_k))
        ov = _F32(override if override is not None else 0.0)
        ev = self.launch(k, -(-n // self.proj_vw), _I32(n), inp["means"], inp["quats"], inp["log_scales"], inp["opacity_logits"],
                          *_sh_args(inp, fr.sh_k), b["cam"], _I32(fr.width), _I32(fr.height), ov, drop_args(fr.drop)[2],
                          _I32(mask), _I32(1 if accumulate else 0), b["radii"],
                          b["v_proj"], out["means"], out["quats"], out["log_scales"], out["opacity_logits"],
                          out["sh"], *self._stats_args(fr, stats), wg=self.proj_wg)
        self._mark("project_bwd", ev)
        return out

    # ------------------------------------------------------------------------------------------
    # stage methods (host numpy in / out, same names and meaning as the reference)
    # ------------------------------------------------------------------------------------------
    def project_fwd(self, g: Gaussians, cam: Camera, near: float = 0.01,
                    opacity_override: float | None = None, drop: Drop | None = None) -> Projected:
        fr = self._new_frame(len(g), cam.width, cam.height, g.sh.shape[1])
        fr.bufs["in"] = self._upload_gaussians(g)
        self._project_device(fr, fr.bufs["in"], cam, near, opacity_override, drop)
        out = self._read_projected(fr)
        self._finish()
        return out

    def _read_projected(self, fr: _Frame) -> Projected:
        n, b = fr.n, fr.bufs
        return Projected(means2d=self._read(b["means2d"], (n, 2), _F32), conics=self._read(b["conics"], (n, 3), _F32),
                         depths=self._read(b["depths"], (n,), _F32), radii=self._read(b["radii"], (n,), _I32),
                         tile_rect=self._read(b["tile_rect"], (n, 4), _I32),
                         colors=self._read(b["colors"], (n, 3), _F32),
                         opacities=self._read(b["opacities"], (n,), _F32))

    def _upload_projected(self, fr: _Frame, proj: Projected) -> None:
        """Host Projected -> the device buffers project_fwd would have written (float32), plus depth
        sort keys: the float bits of t_z for visible rows (all the reference's Bins rank), the
        culled key elsewhere."""
        problem = projected_shape_problem(proj)  # the kernels read N rows of every field
        if problem:
            raise ValueError(problem)
        b = fr.bufs
        radii = np.asarray(proj.radii, _I32)
        depths = np.asarray(proj.depths, _F32)
        keys = np.where(radii > 0, depths.view(_U32), _U32(DEPTH_KEY_CULLED)).astype(_U32)
        for name, arr, dt in (("means2d", proj.means2d, _F32), ("conics", proj.conics, _F32),
                              ("depths", depths, _F32), ("radii", radii, _I32),
                              ("tile_rect", proj.tile_rect, _I32), ("colors", proj.colors, _F32),
                              ("opacities", proj.opacities, _F32), ("depth_keys", keys, _U32),
                              ("gid_vals", np.arange(fr.n, dtype=_U32), _U32)):
            b[name] = self._upload("gauss", name, np.asarray(arr, dt))
        b["ctrl"] = self._upload("small", "ctrl", np.zeros(CTRL_WORDS, _U32))  # as project_fwd leaves it

    def _upload_bins(self, fr: _Frame, bins: Bins) -> None:
        problem = bins_problem(bins, fr.n, fr.width, fr.height)  # the rasterizer would read and write out of bounds
        if problem:
            raise ValueError(f"rasterize: {problem}")
        b = fr.bufs
        fr.counts = len(bins.gid_from_rank), len(bins.gid_from_isect)
        fr.ranks, fr.cap = fr.counts
        b["gid_from_rank"] = self._upload("gauss", "gid_from_rank_in", np.asarray(bins.gid_from_rank, _U32))
        b["offset_from_rank"] = self._upload("gauss", "offset_from_rank_in", np.asarray(bins.offset_from_rank, _U32))
        b["gid_from_isect"] = self._upload("isect", "gid_from_isect_in", np.asarray(bins.gid_from_isect, _I32))
        b["emit_from_isect"] = self._upload("isect", "emit_from_isect_in", np.asarray(bins.emit_from_isect, _U32))
        b["tile_ranges"] = self._upload("tile", "tile_ranges_in", np.asarray(bins.tile_ranges, _I32))

    def bin(self, proj: Projected, width: int, height: int) -> Bins:  # noqa: A003 (stage name)
        problem = bin_problem(proj, width, height)  # the kernels would read and write out of bounds
        if problem:
            raise ValueError(f"bin: {problem}")
        n = proj.means2d.shape[0]
        fr = self._new_frame(n, width, height, 1)
        self._upload_projected(fr, proj)
        # an uploaded projection may break the sync-free bound (a visible rect beyond the grid)
        rect = np.asarray(proj.tile_rect, np.int64).reshape(n, 4)[np.asarray(proj.radii) > 0]
        tiles = (rect[:, 2] - rect[:, 0]) * (rect[:, 3] - rect[:, 1])
        self._bin_device(fr, allow_async=bool(np.all((tiles >= 0) & (tiles <= fr.n_tiles))))
        out = self._read_bins(fr)
        self._finish()
        return out

    def _read_bins(self, fr: _Frame) -> Bins:
        b, v, k = fr.bufs, fr.visible, fr.isects  # an uploaded projection ranks its visible rows only: V
        return Bins(gid_from_rank=self._read(b["gid_from_rank"], (v,), _I32),
                    offset_from_rank=self._read(b["offset_from_rank"], (v + 1,), _I32),
                    gid_from_isect=self._read(b["gid_from_isect"], (k,), _I32),
                    emit_from_isect=self._read(b["emit_from_isect"], (k,), _I32),
                    tile_ranges=self._read(b["tile_ranges"], (fr.n_tiles, 2), _I32))

    def rasterize_fwd(self, proj: Projected, bins: Bins, width: int, height: int,
                      background: Sequence[float] = (0.0, 0.0, 0.0), want_importance: bool = False) -> RasterOut:
        n = proj.means2d.shape[0]
        fr = self._new_frame(n, width, height, 1)
        self._upload_projected(fr, proj)
        self._upload_bins(fr, bins)
        self._raster_fwd(fr, background, want_importance)
        b, H, W = fr.bufs, height, width
        out = RasterOut(rgb=self._read(b["out_rgb"], (H, W, 3), _F32), depth=self._read(b["out_depth"], (H, W), _F32),
                        alpha=self._read(b["out_alpha"], (H, W), _F32), final_T=self._read(b["out_T"], (H, W), _F32),
                        last=self._read(b["out_last"], (H, W), _I32),
                        importance=self._read(b["importance"], (n,), _F32) if want_importance else None)
        self._finish()
        return out

    def rasterize_bwd(self, proj: Projected, bins: Bins, raster_out: RasterOut, v_rgb, v_depth, v_alpha,
                      width: int, height: int, background: Sequence[float] = (0.0, 0.0, 0.0)) -> RasterGrads:
        """VJP of rasterize_fwd reduced per gid (rows of non-visible Gaussians are zero). The forward
        images are recomputed on the device from (proj, bins); `raster_out` is not used."""
        n = proj.means2d.shape[0]
        fr = self._new_frame(n, width, height, 1)
        self._upload_projected(fr, proj)
        self._upload_bins(fr, bins)
        self._raster_fwd(fr, background, False)
        self._raster_bwd(fr, v_rgb, v_depth, v_alpha)
        v = self._read(fr.bufs["v_proj"], (n, V_RECORD), _F32)
        self._finish()
        vis = np.zeros(n, bool)
        vis[np.asarray(bins.gid_from_rank, np.int64)] = True
        v = np.where(vis[:, None], v, 0.0).astype(_F32)  # rows the reduce did not write
        return RasterGrads(v_means2d=v[:, 0:2], v_conics=v[:, 2:5], v_colors=v[:, 5:8], v_opacities=v[:, 8],
                           v_depths=v[:, 9])

    def project_bwd(self, g: Gaussians, cam: Camera, proj: Projected, grads: RasterGrads, near: float = 0.01,
                    opacity_override: float | None = None, grad_fields: Sequence[str] | None = None,
                    drop: Drop | None = None) -> Gaussians:
        """VJP of project_fwd: float32 `Gaussians` of dL/d(raw field). The device recomputes the
        projection from `g` (its own radii decide culling, `drop` included); `proj` is accepted for
        the signature."""
        n = len(g)
        fr = self._new_frame(n, cam.width, cam.height, g.sh.shape[1])
        fr.bufs["in"] = self._upload_gaussians(g)
        self._project_device(fr, fr.bufs["in"], cam, near, opacity_override, drop)
        with np.errstate(over="ignore"):  # float64 cotangents beyond FLT_MAX become +-inf (kernel saturates)
            vp = np.concatenate([np.asarray(grads.v_means2d, _F32).reshape(n, 2),
                                 np.asarray(grads.v_conics, _F32).reshape(n, 3),
                                 np.asarray(grads.v_colors, _F32).reshape(n, 3),
                                 np.asarray(grads.v_opacities, _F32).reshape(n, 1),
                                 np.asarray(grads.v_depths, _F32).reshape(n, 1)], axis=1)
        fr.bufs["v_proj"] = self._upload("gauss", "v_proj_in", vp)
        out = self._project_bwd_device(fr, opacity_override, grad_fields)
        k = fr.sh_k
        res = {f: self._read(out[f], shp, _F32) for f, shp in
               (("means", (n, 3)), ("quats", (n, 4)), ("log_scales", (n, 3)), ("opacity_logits", (n,)),
                ("sh", (n, k, 3)))}
        self._finish()
        return Gaussians(**res)
