"""Persistent device buffers, grouped by index space and grown geometrically.

    scratch = Scratch(handle)
    buf = scratch.get("gauss", "means2d", n, 2 * 4)   # [n, 2] float32, capacity >= n rows
    with scratch.mapped(buf, (n, 2), np.float32) as a: ...   # zero-copy view on CPU devices

Index spaces (reings/backends/base.py): "gauss" (N Gaussians, also ranks), "isect" (K
intersections, also emit slots), "tile" (T tiles), "pixel" (H*W pixels), "small" (control words,
camera record). A buffer is keyed by (space, name); its capacity (bytes) only grows, by at least
1.5x, so a slowly growing N or K never reallocates every call (Brush's crash reports come from
allocation churn: docs/perf_notes.md §7 lesson 3). Nothing here is ever freed before the backend is.

On CPU devices (PoCL) buffers are created with ALLOC_HOST_PTR: the runtime's own host memory, so
`mapped` and host copies are plain memcpys (or none at all) rather than transfers.

On Oclgrind a replaced buffer is kept alive (`retired`) instead of released. Oclgrind (19.10 to
26.03) recycles a released buffer's id for the next allocation, and its uninitialised-value plugin
has no deallocation hook, so a grown buffer that got the recycled id would inherit the old,
smaller shadow memory: kernel stores past the old size are dropped from the shadow and every later
read there is reported as uninitialised although it was written (seen in tests/test_rasterize.py
test_oclgrind_checks). With no id recycled, each new buffer gets a fresh, fully poisoned shadow of
its real size and a genuine read-before-write is still reported. Simulator only; the kept memory
is bounded by the geometric growth (at most 3x the final size per buffer).
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from . import quirks

SPACES = ("gauss", "isect", "tile", "pixel", "small")


class DeviceLimitError(ValueError):
    """A buffer larger than the device can allocate (the message names the buffer, the size and
    the limit). A ValueError, so `reings` prints it as one line."""

GROWTH = 1.5
MIN_BYTES = 64  # OpenCL forbids zero-sized buffers


class Scratch:
    """Buffers by (space, name), each with a capacity that only grows."""

    def __init__(self, handle):
        import pyopencl as cl

        self.handle = handle
        self.context = handle.context
        self.flags = cl.mem_flags.READ_WRITE
        if quirks.is_cpu(handle.device):
            self.flags |= cl.mem_flags.ALLOC_HOST_PTR
        self._bufs: dict[tuple[str, str], tuple[object, int]] = {}  # -> (buffer, capacity in bytes)
        self.allocations = 0  # how many buffers were created (tests check that steady state is 0)
        self.peak_bytes = 0  # high-water mark of nbytes() (replaced buffers are released on growth)
        self.retain = quirks.is_oclgrind(handle.device)  # keep replaced buffers alive (module doc)
        self.max_alloc = int(handle.device.max_mem_alloc_size)  # CL_DEVICE_MAX_MEM_ALLOC_SIZE
        self.retired: list = []

    def get(self, space: str, name: str, rows: int, row_bytes: int):
        """A buffer of at least `rows` rows of `row_bytes` bytes (contents undefined)."""
        hit = self._bufs.get((space, name))
        if hit is not None and hit[1] >= rows * row_bytes:  # the steady state: no checks, no allocation
            return hit[0]
        return self._get(space, name, rows, row_bytes)

    def _get(self, space: str, name: str, rows: int, row_bytes: int):
        import pyopencl as cl

        if space not in SPACES:
            raise ValueError(f"unknown index space {space!r}; one of {SPACES}")
        key = (space, name)
        need = max(int(rows) * int(row_bytes), MIN_BYTES)
        buf, cap = self._bufs.get(key, (None, 0))
        key_old_cap = cap if buf is not None else None
        if buf is None or cap < need:
            if need > self.max_alloc:
                raise DeviceLimitError(
                    f"the {space} buffer {name!r} needs {need} bytes ({rows} rows of {row_bytes}), more than this "
                    f"device's largest allocation, {self.max_alloc} bytes (CL_DEVICE_MAX_MEM_ALLOC_SIZE on "
                    f"{self.handle.device.name.strip()}); use a smaller image or fewer Gaussians, or another device")
            if buf is not None and self.retain:
                self.retired.append(buf)
            cap = min(max(need, int(cap * GROWTH)), self.max_alloc)
            buf = cl.Buffer(self.context, self.flags, cap)
            self._bufs[key] = (buf, cap)
            self.allocations += 1
            # the old buffer (if any) is dropped here, so the live total is the sum of capacities;
            # count the moment both exist too (old + new), as the device saw it
            live = self.nbytes()
            self.peak_bytes = max(self.peak_bytes, live + (0 if key_old_cap is None else key_old_cap))
        return buf

    def nbytes(self) -> int:
        return sum(b.size for b, _ in self._bufs.values())

    def upload(self, space: str, name: str, array: np.ndarray, wait_for=None):
        """Copy a host array into the (space, name) buffer (rows = array.shape[0]); returns the
        buffer. Non-blocking: the host array must stay alive and unchanged until the queue
        passes this copy (the backend keeps references until its final wait)."""
        import pyopencl as cl

        a = np.ascontiguousarray(array)
        if a.ndim == 0:
            a = a.reshape(1)
        rows = a.shape[0]
        row_bytes = a.itemsize * int(np.prod(a.shape[1:], dtype=np.int64))
        buf = self.get(space, name, rows, max(row_bytes, 1))
        if a.nbytes:
            cl.enqueue_copy(self.handle.queue, buf, a, is_blocking=False, wait_for=wait_for)
        return buf

    def suffixed(self, suffix: str) -> "SuffixedScratch":
        """This scratch under names ending in `suffix`: a second set of the same buffers (the
        backend's kept frame slot), allocated, counted and limited here."""
        return SuffixedScratch(self, suffix)

    @contextmanager
    def mapped(self, buf, shape, dtype, write: bool = False, wait_for=None):
        """A numpy view of the first rows of `buf` (zero-copy on CPU devices); valid inside the
        `with` block only."""
        import pyopencl as cl

        dtype = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64))
        if count == 0:
            yield np.empty(shape, dtype)
            return
        flags = cl.map_flags.WRITE if write else cl.map_flags.READ
        arr, ev = cl.enqueue_map_buffer(self.handle.queue, buf, flags, 0, shape, dtype,
                                        wait_for=wait_for, is_blocking=True)
        try:
            yield arr
        finally:
            arr.base.release(self.handle.queue)


class SuffixedScratch:
    """`Scratch.suffixed(suffix)`: the base scratch's `get` with every name ending in `suffix`
    (buffer ("gauss", "radii") is ("gauss", "radii" + suffix) there)."""

    def __init__(self, base: Scratch, suffix: str):
        self.base, self.suffix = base, suffix

    def get(self, space: str, name: str, rows: int, row_bytes: int):
        return self.base.get(space, name + self.suffix, rows, row_bytes)

    @property
    def allocations(self) -> int:
        """The base scratch's allocation count (a lookup kept while it is unchanged is still valid)."""
        return self.base.allocations
