"""ViewWarpCL: the binocular view-consistency term on an OpenCL device (`kernels/view_warp.cl`).

    vw = ViewWarpCL("pocl")
    ev = vw.enqueue(virt_buf, depth_buf, gt_buf, v_virt_buf, v_depth_buf, h, w, fx, baseline)
    loss = vw.read_loss()          # only when asked: one small reduction and a 12-byte read

The training step's form is `enqueue`: device buffers in ([H, W, 3] virtual render, [H, W] rendered
depth of the training view, [H, W, 3] training image), gradients out (v_virt overwritten, v_depth
written or, with accumulate_depth=True, added to what another term left there); nothing is read
back. Three launches (view_warp_smooth, skipped when smooth_weight is 0; view_warp_bwd_depth;
view_warp_bwd_virt), with the gather schedule (GPUs) view_warp_rows before the last, one more without
`edges` (view_warp_edges first: the training image's edge weights, which a caller with a fixed training
image makes once with `edges`); the loss stays on the device as per-pixel values until `read_loss` /
`read_stats` (view_warp_rows there on the CPU schedule, then view_warp_total). `__call__` is the host convenience form
(numpy in and out) and `forward` the diagnostic warped image and validity mask.

The formulas, and what matches what: `reings.backends.reference_view_warp` (float64 twin) and the
kernel file's header. The virtual camera is `reference_view_warp.virtual_camera(camera, baseline)`;
`fx` and `baseline` here are the training camera's focal length in pixels and that same signed
baseline.

This module owns only the term; it imports nothing from the training engine.
"""
from __future__ import annotations

import math

import numpy as np

from .. import reference_view_warp as ref

_KERNELS = ("view_warp_fwd", "view_warp_edges", "view_warp_smooth", "view_warp_bwd_depth", "view_warp_rows",
            "view_warp_bwd_virt", "view_warp_total")
_F, _I = np.float32, np.int32


class ViewWarpCL:
    """The view_warp kernels of one OpenCL device, with their scratch buffers.

    `wg`: work-group size of the per-row kernels (default 1 on CPU devices, 64 on GPUs; a power of
    two); `lwg`: work-group width of the per-pixel kernels (default 64); `cpu_schedule`:
    view_warp_bwd_virt's row-scatter form (default: the device's REINGS_CPU_SCHEDULE) instead of
    the per-pixel gather (both give the same bits). The overrides are for tests."""

    def __init__(self, device, wg: int | None = None, lwg: int | None = None, cpu_schedule: bool | None = None):
        import pyopencl as cl

        from . import quirks
        from .device import open_device
        from .program import library_for
        from .scratch import Scratch

        self.cl = cl
        self.handle = open_device(device) if isinstance(device, str) else device  # a spec or a DeviceHandle
        dev = self.handle.device
        self.wg = int(wg) if wg else (1 if quirks.is_cpu(dev) else 64)
        if self.wg < 1 or self.wg & (self.wg - 1):
            raise ValueError(f"ViewWarpCL: wg must be a power of two, got {self.wg}")
        self.lwg = int(lwg) if lwg else 64
        if cpu_schedule is None:
            cpu_schedule = bool(quirks.build_defines(dev)["REINGS_CPU_SCHEDULE"])
        self.cpu_schedule = bool(cpu_schedule)
        prg = library_for(self.handle).program("view_warp.cl", VW_WG=self.wg,
                                               REINGS_CPU_SCHEDULE=int(self.cpu_schedule))
        self.k = {n: cl.Kernel(prg, n) for n in _KERNELS}  # own kernel objects: instances may share prg
        # scalar argument types, set once (pyopencl's typed invoker: every scalar packed in one go)
        self.k["view_warp_fwd"].set_scalar_arg_dtypes([None, None, None, None, _F, _I, _I])
        self.k["view_warp_edges"].set_scalar_arg_dtypes([None, None, _I, _I])
        self.k["view_warp_smooth"].set_scalar_arg_dtypes([None] * 4 + [_F, _I, _I])
        self.k["view_warp_bwd_depth"].set_scalar_arg_dtypes([None] * 8 + [_F, _F, _F, _I, _I, _I])
        self.k["view_warp_rows"].set_scalar_arg_dtypes([None] * 4 + [_I, _I])
        self.k["view_warp_bwd_virt"].set_scalar_arg_dtypes([None] * 4 + [_I, _I])
        self.k["view_warp_total"].set_scalar_arg_dtypes([None, None, None, _I])
        self.mem = Scratch(self.handle)
        self._last = None  # (h, w, weight, smooth_weight) of the last enqueue
        self._rows_made = False  # view_warp_rows has run on the last enqueue's per-pixel values
        self.events: list = []  # (kernel name, cl.Event) of the last enqueue
        self._total = np.empty(3, np.float32)

    # {{{ device-resident form
    def edges(self, gt_buf, h: int, w: int, out=None, wait_for=None):
        """The smoothness term's image-edge weights of the training image gt_buf ([H, W, 3]) into `out`
        ([H, W, 2] float32; default: this instance's scratch, valid until the next call): a function of the
        image alone, so a caller whose training images stay put makes them once per image and passes
        them to `enqueue`. Returns the buffer."""
        h, w = int(h), int(w)
        if out is None:
            out = self.mem.get("pixel", "vw_edges", h * w, 2 * 4)
        ev = self.k["view_warp_edges"](self.handle.queue, (_pad(w, self.lwg), h), (self.lwg, 1), gt_buf, out, _I(w),
                                       _I(h), wait_for=wait_for)
        self.events = [("view_warp_edges", ev)]
        return out

    def enqueue(self, virt_buf, depth_buf, gt_buf, v_virt_buf, v_depth_buf, h: int, w: int, fx: float,
                baseline: float, weight: float = 1.0, smooth_weight: float = ref.SMOOTH_WEIGHT,
                accumulate_depth: bool = False, wait_for=None, edges=None):
        """Gradients of weight * (L1 + smooth_weight * smoothness) into v_virt_buf ([H, W, 3],
        overwritten) and v_depth_buf ([H, W]; overwritten, or added to with accumulate_depth).
        Buffers are float32 of this device's context. `edges`: `self.edges(gt_buf, ...)` made earlier
        (default: made here, one launch more). Returns the last kernel's event."""
        h, w, gl, gs, nfb = self._scalars(h, w, fx, baseline, weight, smooth_weight)
        rec_tap = self.mem.get("pixel", "vw_rec_tap", h * w, 4)
        rec_g = self.mem.get("pixel", "vw_rec_g", h * w, 6 * 4)
        pix_f = self.mem.get("pixel", "vw_pix_f", h * w, 2 * 4)
        q = self.handle.queue
        grid, local = (_pad(w, self.lwg), h), (self.lwg, 1)
        evs = []
        sxy = rec_g  # a dummy (never read) when there is no smoothness term
        if gs != 0:
            if edges is None:
                edges = self.edges(gt_buf, h, w, wait_for=wait_for)
                evs, wait_for = list(self.events), None
            sxy = self.mem.get("pixel", "vw_sxy", h * w, 2 * 4)
            ev = self.k["view_warp_smooth"](q, grid, local, depth_buf, edges, sxy, pix_f, nfb, _I(w), _I(h),
                                            wait_for=wait_for)
            evs.append(("view_warp_smooth", ev))
            wait_for = None
        ev = self.k["view_warp_bwd_depth"](q, grid, local, virt_buf, depth_buf, gt_buf, sxy, v_depth_buf, rec_tap,
                                           rec_g, pix_f, nfb, gl, gs, _I(bool(accumulate_depth)), _I(w), _I(h),
                                           wait_for=wait_for)
        evs.append(("view_warp_bwd_depth", ev))
        self._rows_made = False
        if self.cpu_schedule:
            ev = self.k["view_warp_bwd_virt"](q, (h,), None, rec_tap, rec_g, self._row_i(h), v_virt_buf, _I(w), _I(h))
        else:  # the gather's windows need the rows' disparity ranges first
            evs.append(("view_warp_rows", self._rows(h, w)))
            ev = self.k["view_warp_bwd_virt"](q, grid, local, rec_tap, rec_g, self._row_i(h), v_virt_buf, _I(w),
                                              _I(h))
        evs.append(("view_warp_bwd_virt", ev))
        self.events = evs  # (kernel, event) of this call, for profiling
        self._last = (h, w, float(weight), float(smooth_weight))
        return ev

    def _row_i(self, h: int):
        return self.mem.get("pixel", "vw_row_i", h, 3 * 4)

    def _rows(self, h: int, w: int):
        """view_warp_rows of the last enqueue's per-pixel values: the rows' loss sums and (valid count, min x0,
        max x0), once per enqueue. Returns the event."""
        self._rows_made = True
        return self.k["view_warp_rows"](self.handle.queue, (self.wg, h), (self.wg, 1),
                                        self.mem.get("pixel", "vw_pix_f", h * w, 2 * 4),
                                        self.mem.get("pixel", "vw_rec_tap", h * w, 4),
                                        self.mem.get("pixel", "vw_row_f", h, 2 * 4), self._row_i(h), _I(w), _I(h))

    def read_stats(self) -> dict:
        """Of the last `enqueue`: l1_sum (sum |warped - gt| over valid pixels), smooth_sum, valid
        (pixel count), valid_fraction, and loss = weight * (l1_sum / 3HW + smooth_weight *
        smooth_sum / Ns) combined in float64 on the host. One launch of view_warp_total and one
        blocking 12-byte read."""
        if self._last is None:
            raise RuntimeError("ViewWarpCL.read_stats before any enqueue")
        h, w, weight, smooth_weight = self._last
        if not self._rows_made:  # the CPU schedule sums the rows only when the loss is read
            self._rows(h, w)
        total = self.mem.get("small", "vw_total", 3, 4)
        self.k["view_warp_total"](self.handle.queue, (self.wg,), (self.wg,), self.mem.get("pixel", "vw_row_f", h, 8),
                                  self.mem.get("pixel", "vw_row_i", h, 12), total, _I(h))
        self.cl.enqueue_copy(self.handle.queue, self._total, total)  # blocking
        gl, gs = ref.term_weights(h, w, weight, smooth_weight)
        l1, sm, n = (float(v) for v in self._total)
        return {"l1_sum": l1, "smooth_sum": sm, "valid": int(n), "valid_fraction": n / (h * w),
                "loss": gl * l1 + gs * sm}

    def read_loss(self) -> float:
        """The loss of the last `enqueue` (see read_stats)."""
        return self.read_stats()["loss"]

    def enqueue_fwd(self, virt_buf, depth_buf, warped_buf, valid_buf, h: int, w: int, fx: float, baseline: float,
                    wait_for=None):
        """The warped virtual image ([H, W, 3], 0 where invalid) and the validity mask ([H, W] 0/1
        float32) into the given buffers (diagnostics). Returns the event."""
        h, w, _, _, nfb = self._scalars(h, w, fx, baseline, 1.0, 0.0)
        return self.k["view_warp_fwd"](self.handle.queue, (_pad(w, self.lwg), h), (self.lwg, 1), virt_buf, depth_buf,
                                       warped_buf, valid_buf, nfb, _I(w), _I(h), wait_for=wait_for)
    # }}}

    # {{{ host forms
    def __call__(self, virt: np.ndarray, depth: np.ndarray, gt: np.ndarray, fx: float, baseline: float,
                 weight: float = 1.0, smooth_weight: float = ref.SMOOTH_WEIGHT,
                 v_depth: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
        """(loss, v_virt [H, W, 3], v_depth [H, W]) of numpy inputs (uploaded as float32).
        `v_depth`: None, or an [H, W] array the depth gradient is added to (accumulate form)."""
        cl, q = self.cl, self.handle.queue
        vi, d, g = _host_inputs(virt, depth, gt)
        h, w = d.shape
        bv = self._upload("vw_virt", vi)
        bd = self._upload("vw_depth", d)
        bg = self._upload("vw_gt", g)
        ov = self.mem.get("pixel", "vw_v_virt", h * w, 12)
        od = self.mem.get("pixel", "vw_v_depth", h * w, 4)
        if v_depth is not None:
            vd0 = np.ascontiguousarray(v_depth, np.float32)
            if vd0.shape != (h, w):
                raise ValueError(f"view_warp: v_depth must be [H, W] = {(h, w)}, got {vd0.shape}")
            cl.enqueue_copy(q, od, vd0)
        self.enqueue(bv, bd, bg, ov, od, h, w, fx, baseline, weight, smooth_weight, accumulate_depth=v_depth is not None)
        v_virt = np.empty((h, w, 3), np.float32)
        v_dep = np.empty((h, w), np.float32)
        cl.enqueue_copy(q, v_virt, ov)
        cl.enqueue_copy(q, v_dep, od)  # blocking
        return self.read_loss(), v_virt, v_dep

    def forward(self, virt: np.ndarray, depth: np.ndarray, fx: float, baseline: float) -> tuple[np.ndarray, np.ndarray]:
        """(warped [H, W, 3] float32, valid [H, W] bool) of numpy inputs."""
        vi, d, _ = _host_inputs(virt, depth, None)
        h, w = d.shape
        bv = self._upload("vw_virt", vi)
        bd = self._upload("vw_depth", d)
        ow = self.mem.get("pixel", "vw_warped", h * w, 12)
        om = self.mem.get("pixel", "vw_valid", h * w, 4)
        self.enqueue_fwd(bv, bd, ow, om, h, w, fx, baseline)
        warped = np.empty((h, w, 3), np.float32)
        valid = np.empty((h, w), np.float32)
        self.cl.enqueue_copy(self.handle.queue, warped, ow)
        self.cl.enqueue_copy(self.handle.queue, valid, om)  # blocking
        return warped, valid > 0.5
    # }}}

    def _upload(self, name: str, a: np.ndarray):
        buf = self.mem.get("pixel", name, a.shape[0] * a.shape[1], a.itemsize * int(np.prod(a.shape[2:], dtype=np.int64)))
        self.cl.enqueue_copy(self.handle.queue, buf, a)  # blocking: `a` may be a temporary
        return buf

    @staticmethod
    def _scalars(h, w, fx, baseline, weight, smooth_weight):
        """Checked launch scalars: (H, W) as ints, (gl, gs, neg_fb) as float32."""
        h, w = int(h), int(w)
        if h < 1 or w < 1:
            raise ValueError(f"view_warp: image size must be positive, got {h}x{w}")
        fx, baseline, weight, smooth_weight = float(fx), float(baseline), float(weight), float(smooth_weight)
        if not (math.isfinite(fx) and fx > 0):
            raise ValueError(f"view_warp: fx must be positive and finite, got {fx}")
        if not math.isfinite(baseline):
            raise ValueError(f"view_warp: baseline must be finite, got {baseline}")
        if not (math.isfinite(weight) and weight >= 0 and math.isfinite(smooth_weight) and smooth_weight >= 0):
            raise ValueError(f"view_warp: weights must be finite and >= 0, got {weight}, {smooth_weight}")
        gl, gs = ref.term_weights(h, w, weight, smooth_weight)
        return h, w, _F(gl), _F(gs), _F(ref.neg_fb(fx, baseline))


def _pad(n: int, m: int) -> int:
    return -(-int(n) // m) * m


def _host_inputs(virt, depth, gt):
    vi = np.ascontiguousarray(virt, np.float32)
    d = np.ascontiguousarray(depth, np.float32)
    if d.ndim != 2 or vi.shape != d.shape + (3,):
        raise ValueError(f"view_warp: virt must be [H, W, 3] and depth [H, W], got {vi.shape} and {d.shape}")
    g = None
    if gt is not None:
        g = np.ascontiguousarray(gt, np.float32)
        if g.shape != vi.shape:
            raise ValueError(f"view_warp: gt must be [H, W, 3] = {vi.shape}, got {g.shape}")
    return vi, d, g
