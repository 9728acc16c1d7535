"""Training losses, each a function returning (loss, dL/d input) for the fit loop to feed into
`render_vjp` (images) or Adam (parameters).

    photometric_loss(rgb, gt, lambda_dssim, form, device)  -> (loss, v_rgb [H,W,3])
        L1 + SSIM of 3DGS; OpenCL kernels (`kernels/loss.cl`) on OpenCL devices, the float64
        reference (`reings.backends.reference_loss`) on device "reference". The device-resident
        form (`photometric_cl(device).enqueue(x_buf, y_buf, v_buf, ...)`, then `read_loss()`)
        takes and writes device buffers; the training engine uses it.
    depth_loss(depth, target, rng, patch_range, margin, w_local, w_global, device) -> (loss, v_depth [H,W])
        DNGaussian's global-local depth normalisation (METHOD.md §2.4), a random patch size per term
        (drawn on the host: `draw_depth_patches`); OpenCL kernels (`kernels/depth_loss.cl`) on
        OpenCL devices, the float64 reference on device "reference" / None. The device-resident form
        (`depth_loss_cl(device).enqueue(depth_buf, target_buf, v_buf, ...)`, then `read_loss()`)
        takes and writes device buffers; the training engine uses it.
    regularizers(params, shape_pena, scale_pena, opa_pena) -> (loss, {"log_scales": .., "opacity_logits": ..})
        DNGaussian's shape / scale / opacity penalties (METHOD.md §2.2) on the raw parameters.

What the loop does with them (DNGaussian, METHOD.md §2.3-2.4): hard depth = depth_loss on a render
with opacity_override=0.95, its v_depth into render_vjp(grad_fields=("means",)), Adam step of
"means"; soft depth = the same on the normal render with grad_fields=("opacity_logits",), step of
"opacity_logits"; then photometric + regularizers, step of every group.
"""
from __future__ import annotations

import numpy as np

from .backends import reference_loss as ref

# {{{ photometric


class PhotometricCL:
    """The photometric loss on an OpenCL device; buffers are kept per image size and reused."""

    def __init__(self, device: str):
        import pyopencl as cl

        from .backends.opencl.device import open_device
        from .backends.opencl.program import library_for

        self.cl = cl
        self.handle = open_device(device)
        lib = library_for(self.handle)
        self.k = {n: lib.get("loss.cl", n) for n in
                  ("ssim_hpass_fwd", "ssim_vpass_fwd", "ssim_hpass_bwd", "ssim_vpass_bwd", "loss_row_sums")}
        ctx = self.handle.context
        self.taps = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                              hostbuf=ref.gaussian_taps().astype(np.float32))
        self._shape = None

    def _alloc(self, h: int, w: int):
        if self._shape == (h, w):
            return
        cl, ctx, mf = self.cl, self.handle.context, self.cl.mem_flags
        img = h * w * 3 * 4
        self.x = cl.Buffer(ctx, mf.READ_ONLY, img)
        self.y = cl.Buffer(ctx, mf.READ_ONLY, img)
        self.h5 = cl.Buffer(ctx, mf.READ_WRITE, 5 * img)
        self.smap = cl.Buffer(ctx, mf.READ_WRITE, img)
        self.d3 = cl.Buffer(ctx, mf.READ_WRITE, 3 * img)
        self.h3 = cl.Buffer(ctx, mf.READ_WRITE, 3 * img)
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

    def enqueue(self, x, y, v, h: int, w: int, w_l1: float, w_ssim: float):
        """Device-resident form: x (rendered) and y (ground truth) are [H,W,3] float32 buffers of
        this device's context, dL/dx is written into the buffer v; nothing is read back. The per-row
        partial sums stay on the device for `read_loss` (valid until the next call). Returns the
        last kernel's event."""
        q = self.handle.queue
        self._alloc(h, w)
        n = h * w * 3
        W, H = np.int32(w), np.int32(h)
        g2 = (w, h)
        k = self._typed
        k("ssim_hpass_fwd", q, g2, x, y, self.taps, self.h5, W, H)
        k("ssim_vpass_fwd", q, g2, self.h5, self.taps, self.smap, self.d3, np.float32(-w_ssim / n), W, H)
        k("ssim_hpass_bwd", q, g2, self.d3, self.taps, self.h3, W, H)
        k("ssim_vpass_bwd", q, g2, self.h3, x, y, self.taps, v, np.float32(w_l1 / n), W, H)
        ev = k("loss_row_sums", q, (h,), self.smap, x, y, self.partial, W, H)
        self._weights = (float(w_l1), float(w_ssim))
        return ev

    def _typed(self, name: str, q, gsize, *args):
        """Launch kernel `name` through pyopencl's typed invoker (set once per kernel: the generic
        one costs ~6.5 us per scalar argument, see backend.typed_invoker)."""
        kern = self.k[name]
        if not getattr(kern, "_reings_typed", False):
            from .backends.opencl.backend import typed_invoker

            typed_invoker(kern, args)
        return kern(q, gsize, None, *args)

    def read_loss(self) -> float:
        """The loss of the last `enqueue` / call (a blocking read of H x 2 partial sums, added in
        float64 on the host)."""
        h, w = self._shape
        n = h * w * 3
        part = np.empty((h, 2), np.float32)
        self.cl.enqueue_copy(self.handle.queue, part, self.partial)  # blocking: waits for the queue
        sums = part.astype(np.float64).sum(axis=0)
        ssim, l1 = sums[0] / n, sums[1] / n
        w_l1, w_ssim = self._weights
        return float(w_l1 * l1 + w_ssim * (1.0 - ssim))


_PER_DEVICE: dict[tuple, object] = {}


def _per_device(cls, device: str):
    """One instance of a loss class per OpenCL device string (its kernels built once; it shares
    the backend's context)."""
    obj = _PER_DEVICE.get((cls, device))
    if obj is None:
        obj = _PER_DEVICE[(cls, device)] = cls(device)
    return obj


def photometric_cl(device: str) -> PhotometricCL:
    """The (cached) PhotometricCL of an OpenCL device string."""
    return _per_device(PhotometricCL, device)


def photometric_loss(rgb: np.ndarray, gt: np.ndarray, lambda_dssim: float = 0.2, form: str = "dngaussian",
                     device: str = "pocl") -> tuple[float, np.ndarray]:
    """(loss, dL/d rgb) of the photometric loss for images [H, W, 3].

    form "dngaussian": L1 + lambda * (1 - SSIM)   (DNGaussian train_llff.py)
    form "3dgs":       (1 - lambda) * L1 + lambda * (1 - SSIM)   (3DGS train.py)
    """
    w_l1, w_ssim = ref.photometric_weights(lambda_dssim, form)
    rgb = np.asarray(rgb)
    gt = np.asarray(gt)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape != gt.shape:
        raise ValueError(f"rgb and gt must be [H, W, 3] of one shape, got {rgb.shape} and {gt.shape}")
    if device == "reference":
        loss, v = ref.photometric_fwd_bwd(rgb, gt, lambda_dssim, form)
        return loss, v.astype(np.float32)
    return photometric_cl(device)(rgb, gt, w_l1, w_ssim)
# }}}

# {{{ depth


class DepthLossCL:
    """DNGaussian's global-local depth loss on an OpenCL device (kernels/depth_loss.cl, 5 launches);
    the device-resident form is `enqueue` (device buffers in and out) then `read_loss`.

    Statistics and per-pixel math are double where the device has cl_khr_fp64 (`fp64=None`: auto),
    so on PoCL and NVIDIA the result is the float64 reference's up to float32 rounding of v_depth;
    without fp64 they are float with each input shifted by its first pixel (kernel header). All
    reductions are fixed-order (deterministic). `wg`: the reduce kernels' work-group size (default
    1 on CPU devices, 256 on GPUs); `lwg`: the other kernels' (default 64); `cpu_schedule`: dl_grad's
    row-per-work-item form (default: the device's REINGS_CPU_SCHEDULE). The overrides are for tests
    (every schedule on PoCL and Oclgrind)."""

    def __init__(self, device: str, wg: int | None = None, fp64: bool | None = None, lwg: int | None = None,
                 cpu_schedule: bool | None = None):
        import pyopencl as cl

        from .backends.opencl import quirks
        from .backends.opencl.device import open_device
        from .backends.opencl.program import library_for
        from .backends.opencl.scratch import Scratch

        self.cl = cl
        self.handle = open_device(device)
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
        prg = library_for(self.handle).program("depth_loss.cl", DL_FP64=int(self.fp64), DL_WG=self.wg,
                                               REINGS_CPU_SCHEDULE=int(self.cpu_schedule))
        self.k = {n: cl.Kernel(prg, n) for n in  # own kernel objects: several instances may share prg
                  ("dl_block_stats", "dl_reduce_stats", "dl_patch_terms", "dl_reduce_terms", "dl_grad",
                  "dl_smooth_rows")}
        self.mem = Scratch(self.handle)
        self._weights = None
        self._smooth = None  # (depth_buf, wx_buf, wy_buf, h, w, w_smooth / sum of weights) of the last call
        self._t = np.empty(8, self.real)  # read_loss's host words

    def enqueue(self, depth_buf, target_buf, v_buf, h: int, w: int, p_local: int, p_global: int,
                margin: float, w_local: float = 0.1, w_global: float = 1.0, smooth=None):
        """Device-resident form: depth (rendered) and target are [H,W] float32 buffers of this
        device's context; dL/d depth is WRITTEN (overwritten, not added) into the [H,W] float32
        buffer v_buf; nothing is read back. The two term losses stay on the device for `read_loss`
        (valid until the next call). Patch sizes must lie in [1, min(h, w)] (`depth_loss` draws and
        clamps them). `smooth`: None, or (wx_buf, wy_buf, scale) to add scale * the edge-aware
        smoothness numerator's gradient (scale = w_smooth / sum of the weights; weights [H,W]
        float32 from `reference_loss.smooth_weights`), fused into the gradient kernel; its loss is
        computed only if `read_loss` is called. Returns the last kernel's event."""
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
        lw, wg = self.lwg, self.wg
        self._call("dl_block_stats", q, (-(-bcap // lw) * lw, 6), (lw, 1), depth_buf, target_buf, bstats, *geo)
        self._call("dl_reduce_stats", q, (wg, 6), (wg, 1), bstats, sstats, *geo)
        mt = max(ml, mg)
        self._call("dl_patch_terms", q, (-(-mt // lw) * lw, 2), (lw, 1), depth_buf, target_buf, bstats, sstats,
                   pcnt, prec, r(margin), *geo)
        self._call("dl_reduce_terms", q, (wg, 2), (wg, 1), sstats, pcnt, prec, pcoef, tstats, *geo)
        gg, gl = ((-(-h // lw) * lw,), (lw,)) if self.cpu_schedule else ((-(-w // lw) * lw, h), (lw, 1))
        swx, swy, ss = (target_buf, target_buf, 0.0) if smooth is None else smooth  # dummies are never read
        ev = self._call("dl_grad", q, gg, gl, depth_buf, target_buf, prec, pcoef, tstats, v_buf, r(margin),
                        r(w_local), r(w_global), *geo, swx, swy, r(ss))
        self._weights = (float(w_local), float(w_global))
        self._smooth = None if smooth is None or ss == 0 else (depth_buf, swx, swy, h, w, float(ss))
        return ev

    def _call(self, name: str, q, gsize, lsize, *args):
        """Launch through pyopencl's typed invoker (see PhotometricCL._typed)."""
        kern = self.k[name]
        if not getattr(kern, "_reings_typed", False):
            from .backends.opencl.backend import typed_invoker

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
            self._call("dl_smooth_rows", q, (-(-h // self.lwg) * self.lwg,), (self.lwg,), depth_buf, swx, swy,
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
                 w_local: float = 0.1, w_global: float = 1.0, smooth=None) -> tuple[float, np.ndarray]:
        """Host form: (loss, v_depth float32 [H, W]) of numpy [H, W] inputs (uploaded as float32);
        `smooth`: None or a `SmoothWeights` and its weight, (SmoothWeights, w_smooth)."""
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
        self.enqueue(db, tb, vb, h, w, p_local, p_global, margin, w_local, w_global, sm)
        v = np.empty((h, w), np.float32)
        cl.enqueue_copy(q, v, vb)  # blocking
        return self.read_loss(), v


def depth_loss_cl(device: str) -> DepthLossCL:
    """The (cached) DepthLossCL of an OpenCL device string."""
    return _per_device(DepthLossCL, device)


def draw_depth_patches(rng: np.random.Generator, patch_range: tuple[int, int], h: int, w: int) -> tuple[int, int]:
    """The two patch sizes of one depth-loss call: uniform in [lo, hi] inclusive, local first (as
    DNGaussian draws them), each clamped to min(h, w). Both training engines draw through this."""
    lo, hi = int(patch_range[0]), int(patch_range[1])
    cap = min(int(h), int(w))
    p_local = min(int(rng.integers(lo, hi + 1)), cap)
    p_global = min(int(rng.integers(lo, hi + 1)), cap)
    return p_local, p_global


class SmoothWeights:
    """The edge weights of one view's depth smoothness term (`reference_loss.smooth_weights`):
    wx, wy [H, W] float32 (what the kernels read) and inv_sum = 1 / (sum wx + sum wy) of those.
    Built once per training view."""

    def __init__(self, target: np.ndarray):
        wx, wy = ref.smooth_weights(target)
        self.wx = np.ascontiguousarray(wx, np.float32)
        self.wy = np.ascontiguousarray(wy, np.float32)
        # the sum of the float32 weights (in float64), as the reference sums what the kernels read
        tot = float(self.wx.sum(dtype=np.float64) + self.wy.sum(dtype=np.float64))
        self.inv_sum = 1.0 / tot if tot > 0 else 0.0


def depth_loss(depth: np.ndarray, target: np.ndarray, rng: np.random.Generator,
               patch_range: tuple[int, int] = (5, 17), margin: float = 0.00025,
               w_local: float = 0.1, w_global: float = 1.0, device: str | None = None,
               smooth: tuple | None = None) -> tuple[float, np.ndarray]:
    """DNGaussian's depth loss on a rendered depth [H, W] against the (constant) mono target:
    w_local * local + w_global * global, each term with its own patch size drawn uniformly from
    [lo, hi] inclusive (local first, as DNGaussian draws them; clamped to the image size).
    Returns (loss, v_depth float32 [H, W]).  What is detached: see
    `reference_loss.depth_norm_loss_fwd_bwd`.

    `smooth`: None, or (SmoothWeights of this target, w_smooth) to add w_smooth times DNGaussian's
    edge-aware smoothness (`reference_loss.depth_smooth_fwd_bwd`; LLFF after iteration 3000).

    device None or "reference": the float64 numpy reference; an OpenCL device string: the kernels
    of kernels/depth_loss.cl (`depth_loss_cl(device)`; host arrays uploaded, v_depth read back)."""
    h, w = np.shape(depth)[:2]
    p_local, p_global = draw_depth_patches(rng, patch_range, h, w)
    if device is None or device == "reference":
        loss, v = ref.global_local_depth_loss(depth, target, p_local, p_global, margin, w_local, w_global)
        if smooth is not None and smooth[1] != 0:
            sw, ws = smooth
            ls, vs = ref.depth_smooth_fwd_bwd(depth, sw.wx, sw.wy)
            loss, v = loss + ws * ls, v + ws * vs
        return loss, v.astype(np.float32)
    return depth_loss_cl(device)(depth, target, p_local, p_global, margin, w_local, w_global, smooth)
# }}}

# {{{ regularizers


def shape_reg(log_scales: np.ndarray) -> tuple[float, np.ndarray]:
    """mean over Gaussians of max scale / min scale; gradient w.r.t. log_scales [N, 3]
    (d/d log s of exp(a)/exp(b) is +ratio at the max axis and -ratio at the min axis; ties go to
    the first axis, as torch.max/min; an isotropic Gaussian gets zero)."""
    ls = np.asarray(log_scales, np.float64)
    n = ls.shape[0]
    g = np.zeros_like(ls)
    if n == 0:
        return 0.0, g
    imax, imin = ls.argmax(axis=1), ls.argmin(axis=1)
    r = np.arange(n)
    ratio = np.exp(ls[r, imax] - ls[r, imin])
    np.add.at(g, (r, imax), ratio / n)
    np.add.at(g, (r, imin), -ratio / n)
    return float(ratio.mean()), g


def scale_reg(log_scales: np.ndarray) -> tuple[float, np.ndarray]:
    """mean over Gaussians of (max scale)^2; gradient w.r.t. log_scales (2 s_max^2 / N at the max axis)."""
    ls = np.asarray(log_scales, np.float64)
    n = ls.shape[0]
    g = np.zeros_like(ls)
    if n == 0:
        return 0.0, g
    imax = ls.argmax(axis=1)
    r = np.arange(n)
    s2 = np.exp(2.0 * ls[r, imax])
    g[r, imax] = 2.0 * s2 / n
    return float(s2.mean()), g


def opacity_reg(opacity_logits: np.ndarray, split: float = 0.2) -> tuple[float, np.ndarray]:
    """DNGaussian's opa_pena = 1 - mean(o^2 | o > 0.2) + mean((1 - o)^2 | o < 0.2), o = sigmoid(logit);
    gradient w.r.t. the logits.  An empty subset contributes 0 to that mean (torch: NaN) and its
    "1 -" stays (value 1 when no opacity exceeds 0.2, mirroring the formula's constant)."""
    a = np.asarray(opacity_logits, np.float64)
    o = 1.0 / (1.0 + np.exp(-a))
    hi, lo = o > split, o < split
    nh, nl = int(hi.sum()), int(lo.sum())
    val = 1.0
    go = np.zeros_like(o)
    if nh:
        val -= float((o[hi] ** 2).mean())
        go[hi] = -2.0 * o[hi] / nh
    if nl:
        val += float(((1.0 - o[lo]) ** 2).mean())
        go[lo] = -2.0 * (1.0 - o[lo]) / nl
    return val, go * o * (1.0 - o)


def regularizers(params: dict, shape_pena: float = 0.0, scale_pena: float = 0.0,
                 opa_pena: float = 0.0) -> tuple[float, dict[str, np.ndarray]]:
    """shape_pena * shape + scale_pena * scale + opa_pena * opacity (DNGaussian, added to the
    photometric loss); gradients (float32) only for the fields with a non-zero weight."""
    loss, grads = 0.0, {}
    if shape_pena or scale_pena:
        g = np.zeros(params["log_scales"].shape)
        if shape_pena:
            v, gs = shape_reg(params["log_scales"])
            loss += shape_pena * v
            g += shape_pena * gs
        if scale_pena:
            v, gs = scale_reg(params["log_scales"])
            loss += scale_pena * v
            g += scale_pena * gs
        grads["log_scales"] = g.astype(np.float32)
    if opa_pena:
        v, go = opacity_reg(params["opacity_logits"])
        loss += opa_pena * v
        grads["opacity_logits"] = (opa_pena * go).astype(np.float32)
    return loss, grads
# }}}
