"""The loss kernels' host code on one OpenCL device: `PhotometricCL` (kernels/photometric.cl, the
photometric stage) and `DepthLossCL` (kernels/depth_loss.cl: the depth_loss stage with the
depth_smooth term fused in). Each has two forms:

    enqueue(device buffers in, gradient buffer out, ...) then read_loss()   the device trainer's
    obj(host arrays, ...) -> (loss, gradient as a host array)                the backend's host
                                                                             loss methods

One instance of each per OpenCLBackend (`backend.photometric_kernels`, `backend.depth_loss_kernels`),
sharing its device handle; tests may build more (DepthLossCL's schedule overrides). The float64
references are `reings.backends.reference_loss`; the host-facing loss functions are
`reings.losses`.
"""
from __future__ import annotations

import os

import numpy as np

from ..reference_loss import gaussian_taps
from .bin_counts import flag_setting
from .device import open_device
from .program import library_for, typed_invoker


def _handle(device):
    """A DeviceHandle from a handle or a device string (opened through the shared cache)."""
    return open_device(device) if isinstance(device, str) else device


SSIM_ROWS = 16  # photometric.cl's CPU schedule: image rows per work-item (passed to the build)
SSIM_TILE = (16, 16)  # photometric.cl's fused GPU kernels: the work-group's tile of pixels (SSIM_TX, SSIM_TY)
SSIM_FUSED_ENV = "REINGS_SSIM_FUSED"  # 0 / 1: the GPU schedule's SSIM in two launches (fused, default) or four


def ssim_tile_local_bytes(tile=SSIM_TILE) -> int:
    """Local memory of ssim_fwd_tile (the larger): 5 planes x 3 channels x (ty + 10) rows x tx floats."""
    return 4 * 5 * 3 * (tile[1] + 10) * tile[0]


def ssim_fused_setting(fused=None) -> bool:
    """`fused`, else $REINGS_SSIM_FUSED (0 or 1), else True."""
    return flag_setting(fused, "fused", SSIM_FUSED_ENV)


class PhotometricCL:
    """The photometric loss on an OpenCL device (a DeviceHandle or a device string); buffers are
    kept per image size and reused. `cpu_schedule` overrides the device's REINGS_CPU_SCHEDULE (the
    SSIM passes a work-item per SSIM_ROWS image rows on CPUs, per pixel on GPUs: the same bits; tests run
    both). `fused` (GPU schedule; None: $REINGS_SSIM_FUSED, else on): each ssim_hpass_* (along W) and its
    ssim_vpass_* (along H) in one launch through a tile in local memory (ssim_fwd_tile, ssim_bwd_tile: the
    same bits, two launches instead of four; docs/perf_notes.md §21), where the device takes the tile's
    work-group and local memory (else the four passes). `vw`: the CPU schedule's elements per vector (8 or 16;
    default 16 where the device's native float vector is 16 wide, else 8; the same bits)."""

    def __init__(self, device, cpu_schedule: bool | None = None, fused: bool | None = None, vw: int | None = None):
        import pyopencl as cl

        self.cl = cl
        self.handle = _handle(device)
        lib = library_for(self.handle)
        from .rasterize import native_lanes

        # the CPU schedule's elements per vector: 16 on AVX-512 (the same sums, the same bits; docs/perf_notes.md §32)
        vw = native_lanes(self.handle.device) if vw is None else int(vw)
        if vw not in (8, 16):
            raise ValueError(f"PhotometricCL: vw must be 8 or 16, got {vw}")
        d = {"SSIM_ROWS": SSIM_ROWS, "SSIM_VW": vw}
        if cpu_schedule is not None:
            d["REINGS_CPU_SCHEDULE"] = int(bool(cpu_schedule))
        self.cpu_schedule = bool(d.get("REINGS_CPU_SCHEDULE", lib.base_defines["REINGS_CPU_SCHEDULE"]))
        dev = self.handle.device
        # the fused kernels' work-group (SSIM_TILE) and local memory (5 W-pass planes of the tile and its halo rows)
        self.fused = (ssim_fused_setting(fused) and not self.cpu_schedule
                      and int(dev.max_work_group_size) >= SSIM_TILE[0] * SSIM_TILE[1]
                      and int(dev.local_mem_size) >= ssim_tile_local_bytes())
        if self.fused:
            d.update(SSIM_TX=SSIM_TILE[0], SSIM_TY=SSIM_TILE[1])
            names = ("ssim_fwd_tile", "ssim_bwd_tile", "loss_row_sums")
        else:
            names = ("ssim_hpass_fwd", "ssim_vpass_fwd", "ssim_hpass_bwd", "ssim_vpass_bwd", "loss_row_sums")
        self.k = {n: lib.get("photometric.cl", n, **d) for n in names}
        ctx = self.handle.context
        self.taps = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                              hostbuf=gaussian_taps().astype(np.float32))
        self._shape = None
        self._weights = None  # (w_l1, w_ssim) of the last enqueue with value=True; None: no loss to read

    def _alloc(self, h: int, w: int):
        if self._shape == (h, w):
            return
        cl, ctx, mf = self.cl, self.handle.context, self.cl.mem_flags
        img = h * w * 3 * 4
        self.x = cl.Buffer(ctx, mf.READ_ONLY, img)
        self.y = cl.Buffer(ctx, mf.READ_ONLY, img)
        self.h5 = None if self.fused else cl.Buffer(ctx, mf.READ_WRITE, 5 * img)
        self.smap = cl.Buffer(ctx, mf.READ_WRITE, img)
        self.d3 = cl.Buffer(ctx, mf.READ_WRITE, 3 * img)
        self.h3 = None if self.fused else cl.Buffer(ctx, mf.READ_WRITE, 3 * img)
        self.v = cl.Buffer(ctx, mf.WRITE_ONLY, img)
        self.partial = cl.Buffer(ctx, mf.WRITE_ONLY, h * 2 * 4)
        self._shape = (h, w)

    def __call__(self, rgb: np.ndarray, gt: np.ndarray, w_l1: float, w_ssim: float) -> tuple[float, np.ndarray]:
        cl, q = self.cl, self.handle.queue
        h, w = rgb.shape[:2]
        self._alloc(h, w)
        cl.enqueue_copy(q, self.x, np.ascontiguousarray(rgb, np.float32))
        cl.enqueue_copy(q, self.y, np.ascontiguousarray(gt, np.float32))
        self.enqueue(self.x, self.y, self.v, h, w, w_l1, w_ssim)
        v = np.empty((h, w, 3), np.float32)
        cl.enqueue_copy(q, v, self.v)
        return self.read_loss(), v

    def enqueue(self, x, y, v, h: int, w: int, w_l1: float, w_ssim: float, value: bool = True):
        """Device-resident form: x (rendered) and y (ground truth) are [H,W,3] float32 buffers of
        this device's context, dL/dx is written into the buffer v; nothing is read back. The per-row
        partial sums stay on the device for `read_loss` (valid until the next call). value=False:
        no loss_row_sums launch (the gradient does not need it: a training step whose loss nobody
        reads; docs/perf_notes.md §11), and `read_loss` raises until the next call with value=True.
        Returns the last kernel's event."""
        q = self.handle.queue
        self._alloc(h, w)
        n = h * w * 3
        W, H = np.int32(w), np.int32(h)
        # a work-item per SSIM_ROWS rows / per pixel
        g2 = ((-(-h // SSIM_ROWS),), (1,)) if self.cpu_schedule else ((w, h), None)
        k = self._typed
        if self.fused:
            tx, ty = SSIM_TILE
            gt = ((-(-w // tx) * tx, -(-h // ty) * ty), (tx, ty))
            k("ssim_fwd_tile", q, gt, x, y, self.taps, self.smap, self.d3, np.float32(-w_ssim / n), W, H)
            ev = k("ssim_bwd_tile", q, gt, self.d3, x, y, self.taps, v, np.float32(w_l1 / n), W, H)
        else:
            k("ssim_hpass_fwd", q, g2, x, y, self.taps, self.h5, W, H)
            k("ssim_vpass_fwd", q, g2, self.h5, self.taps, self.smap, self.d3, np.float32(-w_ssim / n), W, H)
            k("ssim_hpass_bwd", q, g2, self.d3, self.taps, self.h3, W, H)
            ev = k("ssim_vpass_bwd", q, g2, self.h3, x, y, self.taps, v, np.float32(w_l1 / n), W, H)
        if value:
            ev = k("loss_row_sums", q, ((h,), None), self.smap, x, y, self.partial, W, H)
        self._weights = (float(w_l1), float(w_ssim)) if value else None
        return ev

    def _typed(self, name: str, q, sizes, *args):
        """Launch kernel `name` on (global, local) sizes through pyopencl's typed invoker (set once per
        kernel: the generic one costs ~6.5 us per scalar argument, see program.typed_invoker)."""
        kern = self.k[name]
        if not getattr(kern, "_reings_typed", False):
            typed_invoker(kern, args)
        return kern(q, *sizes, *args)

    def read_loss(self) -> float:
        """The loss of the last `enqueue` / call (a blocking read of H x 2 partial sums, added in
        float64 on the host)."""
        if self._weights is None:
            raise RuntimeError("PhotometricCL.read_loss: the last enqueue computed no loss (value=False) or there was none")
        h, w = self._shape
        n = h * w * 3
        part = np.empty((h, 2), np.float32)
        self.cl.enqueue_copy(self.handle.queue, part, self.partial)  # blocking: waits for the queue
        sums = part.astype(np.float64).sum(axis=0)
        ssim, l1 = sums[0] / n, sums[1] / n
        w_l1, w_ssim = self._weights
        return float(w_l1 * l1 + w_ssim * (1.0 - ssim))


# depth_loss.cl's DL_GROUP on the CPU schedule: blocks per dl_block_stats work-item, their sums interleaved (0.7-0.85
# of one block per work-item's time on 2 Xeon cores at 504 x 378, docs/perf_notes.md §41; the same bits)
DL_GROUP_CPU = 8


class DepthLossCL:
    """DNGaussian's global-local depth loss on an OpenCL device (kernels/depth_loss.cl, 5 launches, 3
    fused);
    the device-resident form is `enqueue` (device buffers in and out) then `read_loss`. `device`:
    a DeviceHandle or a device string.

    Statistics and per-pixel math are double where the device has cl_khr_fp64 (`fp64=None`: auto),
    so on PoCL and NVIDIA the result is the float64 reference's up to float32 rounding of v_depth;
    without fp64 they are float with each input shifted by its first pixel (kernel header). All
    reductions are fixed-order (deterministic). `wg`: the reduce kernels' work-group size (default
    1 on CPU devices, 256 on GPUs); `lwg`: the other kernels' (default 64); `cpu_schedule`: dl_grad's
    row-per-work-item form (default: the device's REINGS_CPU_SCHEDULE); `fused`: each reduce in the
    last work-group of the kernel before it (DL_FUSE, 3 launches instead of 5, the same bits; default:
    on the GPU schedule where cross-group reads are known to work, `quirks.volatile_status_words`,
    and wg > 1, unless $REINGS_DL_FUSE=0). The overrides are for tests (every schedule on PoCL and
    Oclgrind); `fused=True` elsewhere (another vendor's GPU) is untested there. `group`: dl_block_stats's blocks
    per work-item, their sums interleaved (DL_GROUP, the same bits; default DL_GROUP_CPU on the CPU schedule
    unfused, else 1)."""

    def __init__(self, device, wg: int | None = None, fp64: bool | None = None, lwg: int | None = None,
                 cpu_schedule: bool | None = None, fused: bool | None = None, group: int | None = None):
        import pyopencl as cl

        from . import quirks
        from .scratch import Scratch

        self.cl = cl
        self.handle = _handle(device)
        dev = self.handle.device
        if fp64 is None:
            fp64 = "cl_khr_fp64" in dev.extensions
        self.fp64 = bool(fp64)
        self.real = np.float64 if self.fp64 else np.float32
        self.wg = int(wg) if wg else (1 if quirks.is_cpu(dev) else 256)
        if self.wg & (self.wg - 1):
            raise ValueError(f"DepthLossCL: wg must be a power of two, got {self.wg}")
        # work-group (along dim 0) of the per-block / per-pixel kernels (no local memory; padding
        # items return at once)
        self.lwg = int(lwg) if lwg else 64
        if cpu_schedule is None:
            cpu_schedule = bool(quirks.build_defines(dev)["REINGS_CPU_SCHEDULE"])
        self.cpu_schedule = bool(cpu_schedule)  # dl_grad: a row per work-item (else a pixel per work-item)
        if fused is None:  # $REINGS_DL_FUSE=0 turns it off (A/B measurements)
            env = os.environ.get("REINGS_DL_FUSE", "").strip()
            if env not in ("", "0", "1"):
                raise ValueError(f"REINGS_DL_FUSE must be 0 or 1, got {env!r}")
            fused = not self.cpu_schedule and self.wg > 1 and quirks.volatile_status_words(dev) and env != "0"
        self.fused = bool(fused)
        # dl_block_stats's blocks per work-item (DL_GROUP: their sums interleaved, the same bits)
        self.group = int(group) if group else (DL_GROUP_CPU if self.cpu_schedule and not self.fused else 1)
        if self.group > 1 and self.fused:
            raise ValueError("DepthLossCL: group > 1 is dl_block_stats's unfused form (DL_FUSE off)")
        prg = library_for(self.handle).program("depth_loss.cl", DL_FP64=int(self.fp64), DL_WG=self.wg,
                                               REINGS_CPU_SCHEDULE=int(self.cpu_schedule), DL_FUSE=int(self.fused),
                                               DL_GROUP=self.group)
        self.k = {n: cl.Kernel(prg, n) for n in  # own kernel objects: several instances may share prg
                  ("dl_block_stats", "dl_reduce_stats", "dl_patch_terms", "dl_reduce_terms", "dl_grad",
                  "depth_smooth_rows")}
        self.mem = Scratch(self.handle)
        # the fused kernels' finished-group counts: zero now, and back to zero at the end of every launch
        self._done = self.mem.get("small", "dl_done", 2, 4)
        cl.enqueue_copy(self.handle.queue, self._done, np.zeros(2, np.int32))  # blocking
        self._weights = None
        self._smooth = None  # (depth_buf, wx_buf, wy_buf, h, w, w_smooth / sum of weights) of the last call
        self._t = np.empty(8, self.real)  # read_loss's host words

    def enqueue(self, depth_buf, target_buf, v_buf, h: int, w: int, p_local: int, p_global: int,
                margin: float, w_local: float = 0.1, w_global: float = 1.0, smooth=None, weight_buf=None):
        """Device-resident form: depth (rendered) and target are [H,W] float32 buffers of this
        device's context; dL/d depth is WRITTEN (overwritten, not added) into the [H,W] float32
        buffer v_buf; nothing is read back. The two term losses stay on the device for `read_loss`
        (valid until the next call). Patch sizes must lie in [1, min(h, w)] (`depth_loss` draws and
        clamps them). `smooth`: None, or (wx_buf, wy_buf, scale) to add scale * the edge-aware
        smoothness numerator's gradient (scale = w_smooth / sum of the weights; weights [H,W]
        float32 from `reference_loss.DepthSmoothWeights`), fused into the gradient kernel; its loss is
        computed only if `read_loss` is called. `weight_buf`: None, or an [H,W] float32 buffer of
        per-pixel weights in [0, 1] on each selected element's squared error (the depth prior's
        confidence: reference_loss.depth_norm_loss_fwd_bwd(weight=)). Returns the last kernel's event."""
        h, w, pl, pg = int(h), int(w), int(p_local), int(p_global)
        for p in (pl, pg):
            if not 1 <= p <= min(h, w):
                raise ValueError(f"depth loss: patch size {p} outside [1, min({h}, {w})]")
        rs = np.dtype(self.real).itemsize
        ml, mg = (h // pl) * (w // pl), (h // pg) * (w // pg)
        bcap = max(ml, mg, h)
        bstats = self.mem.get("pixel", "dl_bstats", 12 * bcap, rs)
        sstats = self.mem.get("small", "dl_sstats", 12, rs)
        pcnt = self.mem.get("pixel", "dl_pcnt", 2 * bcap, 4)
        prec = self.mem.get("pixel", "dl_prec", 16 * bcap, rs)
        pcoef = self.mem.get("pixel", "dl_pcoef", 6 * bcap, rs)
        tstats = self.mem.get("small", "dl_tstats", 8, rs)
        q, r, i32 = self.handle.queue, self.real, np.int32
        geo = (i32(w), i32(h), i32(pl), i32(pg), i32(bcap))
        lw, wg, done = self.lwg, self.wg, self._done
        bw = wg if self.fused else lw  # DL_FUSE: work-groups of DL_WG lanes (the last one reduces)
        nb = -(-bcap // self.group)  # items along dim 0: blocks, or groups of DL_GROUP blocks
        self._call("dl_block_stats", q, (-(-nb // bw) * bw, 6), (bw, 1), depth_buf, target_buf, bstats, *geo,
                   sstats, done)
        if not self.fused:
            self._call("dl_reduce_stats", q, (wg, 6), (wg, 1), bstats, sstats, *geo)
        mt = max(ml, mg)
        wb, has_wt = (target_buf, i32(0)) if weight_buf is None else (weight_buf, i32(1))  # a dummy is never read
        self._call("dl_patch_terms", q, (-(-mt // bw) * bw, 2), (bw, 1), depth_buf, target_buf, bstats, sstats,
                   pcnt, prec, r(margin), *geo, wb, has_wt, pcoef, tstats, done)
        if not self.fused:
            self._call("dl_reduce_terms", q, (wg, 2), (wg, 1), sstats, pcnt, prec, pcoef, tstats, *geo)
        gg, gl = ((-(-h // lw) * lw,), (lw,)) if self.cpu_schedule else ((-(-w // lw) * lw, h), (lw, 1))
        swx, swy, ss = (target_buf, target_buf, 0.0) if smooth is None else smooth  # dummies are never read
        ev = self._call("dl_grad", q, gg, gl, depth_buf, target_buf, prec, pcoef, tstats, v_buf, r(margin),
                        r(w_local), r(w_global), *geo, swx, swy, r(ss), wb, has_wt)
        self._weights = (float(w_local), float(w_global))
        self._smooth = None if smooth is None or ss == 0 else (depth_buf, swx, swy, h, w, float(ss))
        return ev

    def _call(self, name: str, q, gsize, lsize, *args):
        """Launch through pyopencl's typed invoker (see PhotometricCL._typed)."""
        kern = self.k[name]
        if not getattr(kern, "_reings_typed", False):
            typed_invoker(kern, args)
        return kern(q, gsize, lsize, *args)

    def read_loss(self) -> float:
        """w_local * local + w_global * global of the last `enqueue` (one blocking read of the two
        term losses, combined in float64 on the host)."""
        if self._weights is None:
            raise RuntimeError("DepthLossCL.read_loss before any enqueue")
        t, q = self._t, self.handle.queue
        smooth = 0.0
        if self._smooth is not None:  # the smoothness numerator, on demand (training never reads it)
            depth_buf, swx, swy, h, w, ss = self._smooth
            rows = self.mem.get("pixel", "dl_srows", h, t.itemsize)
            self._call("depth_smooth_rows", q, (-(-h // self.lwg) * self.lwg,), (self.lwg,), depth_buf, swx, swy,
                       rows, np.int32(w), np.int32(h))
            hr = np.empty(h, self.real)
            self.cl.enqueue_copy(q, hr, rows)  # blocking
            smooth = ss * float(np.sum(hr, dtype=np.float64))
        self.cl.enqueue_copy(q, t, self.mem.get("small", "dl_tstats", 8, t.itemsize))  # blocking
        w_local, w_global = self._weights
        return float(w_local * float(t[1]) + w_global * float(t[5])) + smooth

    def term_stats(self) -> np.ndarray:
        """[2, 4] (count of selected elements, term loss, E, mean_all: kernels/depth_loss.cl) of the last call
        (local, global); for tests and diagnostics."""
        self.read_loss()
        return self._t.reshape(2, 4).astype(np.float64)

    def __call__(self, depth: np.ndarray, target: np.ndarray, p_local: int, p_global: int, margin: float,
                 w_local: float = 0.1, w_global: float = 1.0, smooth=None,
                 weight: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        """Host form: (loss, v_depth float32 [H, W]) of numpy [H, W] inputs (uploaded as float32);
        `smooth`: None or (DepthSmoothWeights, w_smooth); `weight`: None or [H, W] per-pixel weights."""
        cl, q = self.cl, self.handle.queue
        d = np.ascontiguousarray(depth, np.float32)
        t = np.ascontiguousarray(target, np.float32)
        if d.ndim != 2 or d.shape != t.shape:
            raise ValueError(f"depth and target must be [H, W] of one shape, got {d.shape} and {t.shape}")
        h, w = d.shape
        db = self.mem.get("pixel", "dl_depth", h * w, 4)
        tb = self.mem.get("pixel", "dl_target", h * w, 4)
        vb = self.mem.get("pixel", "dl_v", h * w, 4)
        cl.enqueue_copy(q, db, d)
        cl.enqueue_copy(q, tb, t)
        sm = None
        if smooth is not None and smooth[1] != 0:
            sw, ws = smooth
            bx = self.mem.get("pixel", "dl_swx", h * w, 4)
            by = self.mem.get("pixel", "dl_swy", h * w, 4)
            cl.enqueue_copy(q, bx, sw.wx)
            cl.enqueue_copy(q, by, sw.wy)
            sm = (bx, by, ws * sw.inv_sum)
        wb = None
        if weight is not None:
            wa = np.ascontiguousarray(weight, np.float32)
            if wa.shape != (h, w):
                raise ValueError(f"depth loss: weight must be [H, W] = {(h, w)}, got {wa.shape}")
            wb = self.mem.get("pixel", "dl_weight", h * w, 4)
            cl.enqueue_copy(q, wb, wa)
        self.enqueue(db, tb, vb, h, w, p_local, p_global, margin, w_local, w_global, sm, wb)
        v = np.empty((h, w), np.float32)
        cl.enqueue_copy(q, v, vb)  # blocking
        return self.read_loss(), v
