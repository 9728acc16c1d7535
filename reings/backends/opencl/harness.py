"""The OpenCL measuring harness of `reings bench` and bench/*.py: pyopencl-level instruments that
need the OpenCL runtime itself, kept here so that nothing outside `reings/backends/` imports
pyopencl.

    DeviceBytes     bytes of OpenCL buffers alive / their peak while a `with` block is open
    ClCalls         OpenCL commands and host syncs issued inside a `with` block
    sort_comparison numpy argsort vs our radix sort vs pyopencl.algorithm.RadixSort on uint64 keys
    device_info     the device, driver and versions of an OpenCLBackend (one dict per bench record)
    launches_stubbed  every kernel launch a no-op inside a `with` block (host cost alone)
"""
from __future__ import annotations

import statistics
import time
import warnings
from contextlib import contextmanager

import numpy as np


def _median(xs):
    return float(statistics.median(xs)) if xs else float("nan")


def device_info(be) -> dict:
    """Device, driver, platform / OpenCL C versions, compute units and binning mode (`bin_mode`:
    auto / sync / async, docs/perf_notes.md §8) of OpenCLBackend `be`."""
    d, p = be.handle.device, be.handle.platform
    return dict(device=be.device_name, driver=d.driver_version.strip(), platform_version=p.version.strip(),
                opencl_c=d.opencl_c_version.strip(), compute_units=int(d.max_compute_units), spec=be.spec,
                bin_mode=be.bin_mode)


def sort_comparison(be, keys: np.ndarray, tbits: int, repeats: int, warmup: int, which: str) -> dict:
    """numpy stable argsort vs our RadixSort vs pyopencl's RadixSort on the same uint64 keys."""
    import pyopencl as cl

    n = int(keys.size)
    end_bit = 32 + tbits
    res = dict(n=n, end_bit=end_bit)
    ts = []
    for i in range(max(1, repeats // 4) + 1):
        t0 = time.perf_counter()
        order = np.argsort(keys, kind="stable")
        if i:
            ts.append(time.perf_counter() - t0)
    res["numpy_ms"] = 1e3 * _median(ts)
    if which in ("all", "ours"):
        from .sort import RadixSort

        q, ctx = be.queue, be.handle.context
        mf = cl.mem_flags
        src_k = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=keys)
        vals = np.arange(n, dtype=np.uint32)
        src_v = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=vals)
        kb = cl.Buffer(ctx, mf.READ_WRITE, keys.nbytes)
        vb = cl.Buffer(ctx, mf.READ_WRITE, vals.nbytes)
        with warnings.catch_warnings():  # the backend's sorters already retrieved these kernels
            warnings.simplefilter("ignore")
            sorter = RadixSort(be.handle)
            sorter.warm(True)
        ts, dev = [], []
        for i in range(warmup + repeats):
            cl.enqueue_copy(q, kb, src_k)
            cl.enqueue_copy(q, vb, src_v)
            q.finish()
            t0 = time.perf_counter()
            ko, vo, ev = sorter.sort_pairs(kb, vb, n, 0, end_bit, key64=True)
            q.finish()
            if i >= warmup:
                ts.append(time.perf_counter() - t0)
        out = np.empty(n, np.uint32)
        cl.enqueue_copy(q, out, vo)
        res["ours_ms"] = 1e3 * _median(ts)
        res["ours_correct"] = bool(np.array_equal(out, order))
        res["speedup_vs_numpy"] = res["numpy_ms"] / res["ours_ms"]
    if which == "all":
        try:
            import pyopencl.array as cla
            from pyopencl.algorithm import RadixSort as PyRadixSort

            prs = PyRadixSort(be.handle.context, "unsigned long *keys, unsigned int *vals", key_expr="keys[i]",
                              sort_arg_names=["keys", "vals"], key_dtype=np.uint64)
            ka = cla.to_device(be.queue, keys)
            va = cla.to_device(be.queue, np.arange(n, dtype=np.uint32))
            ts = []
            for i in range(1 + max(1, repeats // 8)):
                t0 = time.perf_counter()
                (_, vs), _ = prs(ka, va, key_bits=end_bit, queue=be.queue)
                be.queue.finish()
                if i:
                    ts.append(time.perf_counter() - t0)
            res["pyopencl_ms"] = 1e3 * _median(ts)
            res["pyopencl_correct"] = bool(np.array_equal(vs.get(), order))
        except Exception as e:  # pragma: no cover - depends on the device's compiler
            res["pyopencl_error"] = f"{type(e).__name__}: {e}"[:200]
    return res


class DeviceBytes:
    """Bytes of OpenCL buffers alive (and their high-water mark) while the `with` block is open,
    by making `pyopencl.Buffer` a tracking subclass (isinstance checks still hold). Counts every
    buffer created through `pyopencl.Buffer` in that time: the backend's scratch, the trainer's
    state, the sorter's and the loss kernels' buffers. Not counted: the driver's own memory
    (context, kernels), which torch's `max_memory_allocated` (gsplat's figure) leaves out too.

        with DeviceBytes() as mem: ...
        mem.peak_bytes, mem.live_bytes; mem.reset_peak()
    """

    def __init__(self):
        self.live_bytes = 0
        self.peak_bytes = 0
        self._orig = None

    def reset_peak(self) -> None:
        self.peak_bytes = self.live_bytes

    def __enter__(self):
        import weakref

        import pyopencl as cl

        self._orig = orig = cl.Buffer
        mem = self

        class TrackedBuffer(orig):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                n = int(self.size)
                mem.live_bytes += n
                mem.peak_bytes = max(mem.peak_bytes, mem.live_bytes)
                weakref.finalize(self, DeviceBytes._freed, mem, n)

        cl.Buffer = TrackedBuffer
        return self

    @staticmethod
    def _freed(mem, n: int) -> None:
        mem.live_bytes -= n

    def __exit__(self, *exc):
        import pyopencl as cl

        cl.Buffer = self._orig
        return False


class ClCalls:
    """Counts the OpenCL commands and host syncs issued inside a `with` block, by wrapping pyopencl's
    entry points (every kernel launch goes through pyopencl._cl.enqueue_nd_range_kernel, whether
    from `kernel(queue, ...)` or `enqueue_nd_range_kernel`).

        launches   kernel launches            copies  enqueue_copy calls (reads_blocking: the
        fills      enqueue_fill_buffer        blocking device -> host ones among them)
        maps       enqueue_map_buffer         finishes  queue.finish();  waits  Event.wait / cl.wait_for_events
        syncs      reads_blocking + blocking writes + blocking maps + finishes + waits
    """

    KEYS = ("launches", "copies", "reads_blocking", "writes_blocking", "fills", "maps", "maps_blocking",
            "finishes", "waits")

    def __init__(self):
        self.n = dict.fromkeys(self.KEYS, 0)
        self._saved = []

    @property
    def syncs(self) -> int:
        n = self.n
        return n["reads_blocking"] + n["writes_blocking"] + n["maps_blocking"] + n["finishes"] + n["waits"]

    def as_dict(self, per: int = 1) -> dict:
        d = {k: v / per for k, v in self.n.items()}
        d["syncs"] = self.syncs / per
        return d

    def _patch(self, obj, name, wrapper_factory):
        orig = getattr(obj, name)
        self._saved.append((obj, name, orig))
        setattr(obj, name, wrapper_factory(orig))

    def __enter__(self):
        import pyopencl as cl
        import pyopencl._cl as _cl

        n = self.n

        def launch(orig):
            def f(*a, **k):
                n["launches"] += 1
                return orig(*a, **k)
            return f

        def copy(orig):
            def f(queue, dest, src, **k):
                n["copies"] += 1
                if k.get("is_blocking", True):
                    if isinstance(dest, np.ndarray):
                        n["reads_blocking"] += 1
                    elif isinstance(src, np.ndarray):
                        n["writes_blocking"] += 1
                return orig(queue, dest, src, **k)
            return f

        def count(key):
            def fac(orig):
                def f(*a, **k):
                    n[key] += 1
                    return orig(*a, **k)
                return f
            return fac

        def mapb(orig):
            def f(*a, **k):
                n["maps"] += 1
                if k.get("is_blocking", True):
                    n["maps_blocking"] += 1
                return orig(*a, **k)
            return f

        self._patch(_cl, "enqueue_nd_range_kernel", launch)
        self._patch(cl, "enqueue_copy", copy)
        self._patch(cl, "enqueue_fill_buffer", count("fills"))
        self._patch(cl, "enqueue_map_buffer", mapb)
        self._patch(cl.CommandQueue, "finish", count("finishes"))
        self._patch(cl.Event, "wait", count("waits"))
        self._patch(cl, "wait_for_events", count("waits"))
        return self

    def __exit__(self, *exc):
        for obj, name, orig in reversed(self._saved):
            setattr(obj, name, orig)
        self._saved = []
        return False


@contextmanager
def launches_stubbed():
    """Inside the block every kernel launch is a no-op (pyopencl._cl.enqueue_nd_range_kernel
    replaced): what the host costs per step before the driver (bench/peer_step.py --overhead)."""
    import pyopencl._cl as _cl

    orig = _cl.enqueue_nd_range_kernel
    _cl.enqueue_nd_range_kernel = lambda *a, **k: None
    try:
        yield
    finally:
        _cl.enqueue_nd_range_kernel = orig
