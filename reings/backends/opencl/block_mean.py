"""BlockMeanCL: the block mean and its adjoint on an OpenCL device (`kernels/block_mean.cl`).

    bm = BlockMeanCL("pocl")
    bm.fwd(a_buf, out_buf, h, w, c, scale)                      # [H, W, C] -> [H // s, W // s, C]
    bm.bwd(v_buf, full_buf, h, w, c, scale, accumulate=False)   # the adjoint, written or added

The device-resident forms (`fwd`, `bwd`) take float32 buffers and enqueue one launch each; nothing is
read back. `fwd_host` / `bwd_host` are the host conveniences (numpy in and out). The formulas, and what
matches what: the kernel file's header and `reings.backends.reference_block_mean` (the float64 twin
block_mean_fwd / block_mean_bwd, and the float32 mirror of these kernels that the host trainer runs).

This module owns only the stage; it imports nothing from the training engine.
"""
from __future__ import annotations

import numpy as np

from .. import reference_block_mean as ref

_F, _I = np.float32, np.int32


class BlockMeanCL:
    """The block_mean kernels of one OpenCL device (a spec or a DeviceHandle). `wg`: the work-group
    size of the one-element-per-work-item launches (the global size rounded up to it)."""

    def __init__(self, device, wg: int = 64):
        import pyopencl as cl

        from .device import open_device
        from .program import library_for
        from .scratch import Scratch

        self.cl = cl
        self.handle = open_device(device) if isinstance(device, str) else device
        prg = library_for(self.handle).program("block_mean.cl")
        self.k_fwd = cl.Kernel(prg, "block_mean_fwd")  # own kernel objects: instances may share prg
        self.k_bwd = cl.Kernel(prg, "block_mean_bwd")
        # scalar argument types, set once (pyopencl's typed invoker: every scalar packed in one go)
        self.k_fwd.set_scalar_arg_dtypes([_I, _I, _I, _I, _I, _F, None, None])
        self.k_bwd.set_scalar_arg_dtypes([_I, _I, _I, _I, _I, _I, _F, _I, None, None])
        self.wg = int(wg)
        if self.wg < 1:
            raise ValueError(f"BlockMeanCL: wg must be >= 1, got {wg}")
        self.mem = Scratch(self.handle)
        self.events: list = []  # (kernel name, cl.Event) of the last launch

    # {{{ device-resident form
    def fwd(self, a_buf, out_buf, h: int, w: int, c: int, scale: int, wait_for=None):
        """out_buf [H // s, W // s, C] = the block means of a_buf [H, W, C] (float32 buffers). Returns
        the event (None when the pooled image is empty: nothing enqueued)."""
        h, w, c, s, ho, wo = _sizes(h, w, c, scale)
        n = ho * wo * c
        self.events = []
        if n == 0:
            return None
        ev = self.k_fwd(self.handle.queue, (_pad(n, self.wg),), (self.wg,), _I(n), _I(w), _I(wo), _I(c), _I(s),
                        ref.block_mean_inv(s), a_buf, out_buf, wait_for=wait_for)
        self.events = [("block_mean_fwd", ev)]
        return ev

    def bwd(self, v_buf, out_buf, h: int, w: int, c: int, scale: int, accumulate: bool = False, wait_for=None):
        """The adjoint: out_buf [H, W, C] = v_buf [H // s, W // s, C] / s^2 spread over each block, 0 on the
        dropped rows and columns; written, or added with accumulate. Returns the event (None for an
        empty image)."""
        h, w, c, s, ho, wo = _sizes(h, w, c, scale)
        n = h * w * c
        self.events = []
        if n == 0:
            return None
        ev = self.k_bwd(self.handle.queue, (_pad(n, self.wg),), (self.wg,), _I(n), _I(w), _I(c), _I(s), _I(ho),
                        _I(wo), ref.block_mean_inv(s), _I(bool(accumulate)), v_buf, out_buf, wait_for=wait_for)
        self.events = [("block_mean_bwd", ev)]
        return ev
    # }}}

    # {{{ host forms
    def fwd_host(self, a: np.ndarray, scale: int) -> np.ndarray:
        """The block means of a numpy [H, W] or [H, W, C] image (uploaded as float32), float32."""
        a = np.ascontiguousarray(a, _F)
        h, w, c, s, ho, wo = _sizes(a.shape[0], a.shape[1], _channels(a.shape), scale)
        src = self._upload("bm_a", a)
        out = self.mem.get("pixel", "bm_out", max(ho * wo, 1), 4 * c)
        self.fwd(src, out, h, w, c, s)
        res = np.empty((ho, wo) + a.shape[2:], _F)
        if res.size:
            self.cl.enqueue_copy(self.handle.queue, res, out)  # blocking
        return res

    def bwd_host(self, v: np.ndarray, shape, scale: int, into: np.ndarray | None = None) -> np.ndarray:
        """The adjoint of a numpy cotangent v [H // s, W // s(, C)]: a new float32 array of `shape`, or with
        `into` given, into + it (`into` uploaded, then the kernel's accumulate form; `into` itself unchanged)."""
        shape = tuple(int(x) for x in shape)
        v = np.ascontiguousarray(v, _F)
        h, w, c, s, ho, wo = _sizes(shape[0], shape[1], _channels(shape), scale)
        if v.shape != (ho, wo) + shape[2:]:
            raise ValueError(f"block_mean_bwd: v must be {(ho, wo) + shape[2:]}, got {v.shape}")
        src = self._upload("bm_v", v)
        out = self.mem.get("pixel", "bm_full", max(h * w, 1), 4 * c)
        if into is not None:
            base = np.ascontiguousarray(into, _F)
            if base.shape != shape:
                raise ValueError(f"block_mean_bwd: into must be {shape}, got {base.shape}")
            if base.size:
                self.cl.enqueue_copy(self.handle.queue, out, base)
        self.bwd(src, out, h, w, c, s, accumulate=into is not None)
        res = np.empty(shape, _F)
        if res.size:
            self.cl.enqueue_copy(self.handle.queue, res, out)  # blocking
        return res
    # }}}

    def _upload(self, name: str, a: np.ndarray):
        buf = self.mem.get("pixel", name, max(a.shape[0] * a.shape[1], 1), a.itemsize * _channels(a.shape))
        if a.size:
            self.cl.enqueue_copy(self.handle.queue, buf, a)  # blocking: `a` may be a temporary
        return buf


def _channels(shape) -> int:
    """C of an [H, W] (1) or [H, W, C] image."""
    if len(shape) not in (2, 3):
        raise ValueError(f"block_mean: an image [H, W] or [H, W, C], got shape {tuple(shape)}")
    return int(shape[2]) if len(shape) == 3 else 1


def _sizes(h, w, c, scale) -> tuple[int, int, int, int, int, int]:
    """Checked (H, W, C, s, Ho, Wo)."""
    h, w, c = int(h), int(w), int(c)
    if h < 0 or w < 0 or c < 1:
        raise ValueError(f"block_mean: sizes must be H, W >= 0 and C >= 1, got {h}x{w}x{c}")
    ho, wo, s = ref.block_sizes((h, w), scale)
    return h, w, c, s, ho, wo


def _pad(n: int, m: int) -> int:
    return -(-int(n) // m) * m
