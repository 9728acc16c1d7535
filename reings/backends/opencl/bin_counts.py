"""The binning's counts (V ranked Gaussians, K intersections, the visible count) and the sync-free
binning mode of `OpenCLBackend` (docs/perf_notes.md §8).

    mode = bin_mode_setting(None)          # "sync" (default) | "auto" | "async"; REINGS_BIN overrides
    budget = bin_budget_setting(None)      # auto's share of the device memory; REINGS_BIN_BUDGET
    cap = isect_capacity(n, n_tiles)       # the bound: K <= V * n_tiles <= N * n_tiles
    choose_binning(mode, cpu, cap, max_alloc, global_mem, budget) -> "sync" | "async"
    ring = CountsRing(handle)              # pinned host words that the reads of ctrl land in
    c = ring.read(ctrl, history)           # non-blocking read of ctrl = (V, K, visible) -> DeviceCounts
    c.get() -> (visible, K)                # waits for that read only if the queue has not passed it
    ring.poll()                            # resolves every read the queue has passed (no wait)

The control words of a frame slot (`ctrl`, CTRL_WORDS uint32, kernels/bin.cl): ctrl[CTRL_RANKED] = V,
the Gaussians with a depth key (t_z > near), a prefix of the depth order and the launch bound of
bin_emit and the reduces; ctrl[CTRL_ISECTS] = K; ctrl[CTRL_VISIBLE] = the visible Gaussians
(radii > 0), the statistic reported as "visible" (V counts also the Gaussians culled for another
reason than the near plane: their z key lets forwards that cull differently share one depth order,
OpenCLBackend "Depth orders"; they have no tile, so they change neither K nor any output).

Sync (the default, BIN_DEFAULT): the backend reads ctrl back with one blocking read per forward
and sizes the K buffers and launches with V and K. Async (sync-free): every K-sized buffer of the frame
is allocated at the bound `isect_capacity`, so nothing can overflow; V and K stay in the ctrl
buffer, where bin_emit, the tile sort, tile_ranges and the reduces read them (their `counts,
count_at` arguments); the launch sizes come from an estimate of K (`OpenCLBackend._isect_estimate`:
the largest of the last K's of the frame slot that are already known without waiting), and the
kernels loop to the device count, so any K up to the bound is handled exactly. The counts are read
back without blocking into a row of a pinned ring, resolved when first asked.

Memory of the bound, bytes per intersection of capacity (`isect_bound_bytes`): per frame slot the
six uint32 arrays tile_keys, emit_vals, gid_from_emit, gid_from_isect and the tile sorter's key
and value scratch (24 B) plus the sorter's histogram (at most 2^8 bins per virtual block of 2048
pairs: 0.5 B) and on CPUs the forward's vector sets raster_hits (4 B, kernels/rasterize.cl RASTER_HITS; not in
the bound below, which "auto" takes for GPUs only); in slot 0 the importance records raster_imp_emit (4 B, importance
renders only);
shared by both slots the backward's gradient records raster_v_emit (4 * V_RECORD = 40 B). Both
slots: 93 B per intersection (101 B on CPUs with raster_hits).
"""
from __future__ import annotations

import os
from collections import deque

import numpy as np

from ..base import V_RECORD

BIN_MODES = ("auto", "sync", "async")
BIN_DEFAULT = "sync"  # measured (docs/results.md §26): no end-to-end gain on an H100 run, ~100x the memory of K
BIN_ENV = "REINGS_BIN"  # overrides the default mode (BIN_DEFAULT) of a backend made without one
BIN_BUDGET = 0.25  # auto: async only if the bound's bytes fit this fraction of the device's memory
BIN_BUDGET_ENV = "REINGS_BIN_BUDGET"  # overrides BIN_BUDGET (a process sharing its GPU: a smaller share)
ISECT_LIMIT = 2**31 - 2**24  # the kernels index intersections with int32 (grid-stride loops included)
SLOT_BYTES = 6 * 4 + 0.5  # per intersection and frame slot: six uint32 arrays + the sort histogram
IMPORTANCE_BYTES = 4  # raster_imp_emit, slot 0
SHARED_BYTES = 4 * V_RECORD  # raster_v_emit, shared by the slots
STATS_ROWS = 256  # rows of the pinned ring (reads in flight at most before the oldest is waited for)
CTRL_RANKED, CTRL_ISECTS, CTRL_VISIBLE = 0, 1, 2  # the words of a frame slot's ctrl (module docstring)
CTRL_WORDS = 3


def choice_setting(value: str | None, name: str, env: str, default: str, choices: tuple) -> str:
    """A backend's string setting: `value`, else $`env`, else `default`; lower-cased and checked
    against `choices` (the error names the argument `name` or the variable)."""
    m = value if value is not None else (os.environ.get(env) or default)
    m = m.strip().lower()
    if m not in choices:
        raise ValueError(f"{name if value is not None else env} must be one of {choices}, got {m!r}")
    return m


def flag_setting(value, name: str, env: str, default: bool = True) -> bool:
    """A backend's on / off setting: `value` (a bool, or "0" / "1"), else $`env` ("0" or "1"), else `default`;
    anything else is refused (the error names the argument `name` or the variable)."""
    raw = value if value is not None else (os.environ.get(env) or None)
    if raw is None:
        return default
    if isinstance(raw, bool):
        return raw
    if str(raw).strip() in ("0", "1"):
        return str(raw).strip() == "1"
    raise ValueError(f"{name if value is not None else env} must be 0 or 1, got {raw!r}")


def bin_mode_setting(mode: str | None) -> str:
    """The binning mode of a backend: `mode`, else $REINGS_BIN, else BIN_DEFAULT ("sync"); checked."""
    return choice_setting(mode, "bin_mode", BIN_ENV, BIN_DEFAULT, BIN_MODES)


def bin_budget_setting(budget: float | None) -> float:
    """auto's budget, a fraction of the device's memory in (0, 1]: `budget`, else
    $REINGS_BIN_BUDGET, else BIN_BUDGET (`reings eval --cluster local --runs-per-gpu K` gives its
    GPU workers BIN_BUDGET / K)."""
    raw = budget if budget is not None else (os.environ.get(BIN_BUDGET_ENV) or BIN_BUDGET)
    try:
        b = float(raw)
    except ValueError:
        b = float("nan")
    if not 0.0 < b <= 1.0:  # also NaN
        src = "bin_budget" if budget is not None else BIN_BUDGET_ENV
        raise ValueError(f"{src} must be a fraction in (0, 1], got {raw!r}")
    return b


def isect_capacity(n: int, n_tiles: int) -> int:
    """The bound on K: every visible Gaussian's tile rect lies in the grid, so K <= N * n_tiles."""
    return int(n) * int(n_tiles)


def isect_bound_bytes(cap: int, slots: int = 2) -> int:
    """Device bytes of every K-sized buffer at capacity `cap` (module docstring), both slots."""
    return int(cap * (slots * SLOT_BYTES + IMPORTANCE_BYTES + SHARED_BYTES))


def choose_binning(mode: str, cpu: bool, cap: int, max_alloc: int, global_mem: int,
                   budget: float = BIN_BUDGET) -> str:
    """"sync" or "async" for one forward of capacity `cap`. "sync": always. "async": unless the
    bound cannot be allocated (its largest buffer over max_alloc, or beyond int32 indexing).
    "auto": async only on non-CPU devices whose memory holds the bound within `budget` of it."""
    if mode == "sync" or cap >= ISECT_LIMIT or cap * SHARED_BYTES > max_alloc:
        return "sync"
    if mode == "async":
        return "async"
    return "async" if not cpu and isect_bound_bytes(cap) <= budget * global_mem else "sync"


class DeviceCounts:
    """(visible, K) of one sync-free forward: a non-blocking read of ctrl into a row of the pinned
    ring. `get()` resolves it (waiting only if the queue has not passed the read) and appends K to
    the frame slot's `history` (the launch estimates of later forwards)."""

    __slots__ = ("host", "event", "history", "value")

    def __init__(self, host, event, history: deque):
        self.host, self.event, self.history, self.value = host, event, history, None

    def done(self) -> bool:
        """True once the read has completed (a status query, no wait)."""
        return self.value is not None or self.event.command_execution_status == 0  # CL_COMPLETE

    def get(self) -> tuple[int, int]:
        if self.value is None:
            if not self.done():
                self.event.wait()  # an error status raises here
            self.value = (int(self.host[CTRL_VISIBLE]), int(self.host[CTRL_ISECTS]))
            self.host = self.event = None  # the event is complete: dropping it waits for nothing
            self.history.append(self.value[1])
        return self.value


class CountsRing:
    """Rows of CTRL_WORDS uint32 in pinned host memory (a mapped ALLOC_HOST_PTR buffer: a non-blocking
    read into pageable memory is synchronous on some drivers), one per sync-free forward, reused
    cyclically. A row's previous read is resolved before the row is reused; every read's event is
    held until it completes (pyopencl's event of a non-blocking copy waits when it is dropped)."""

    def __init__(self, handle, rows: int = STATS_ROWS):
        import pyopencl as cl

        self.cl, self.queue = cl, handle.queue
        mf = cl.mem_flags
        self.buf = cl.Buffer(handle.context, mf.READ_WRITE | mf.ALLOC_HOST_PTR, rows * 4 * CTRL_WORDS)
        self.host, _ = cl.enqueue_map_buffer(self.queue, self.buf, cl.map_flags.READ | cl.map_flags.WRITE, 0,
                                             (rows, CTRL_WORDS), np.uint32, is_blocking=True)
        self.owner: list[DeviceCounts | None] = [None] * rows
        self.pending: deque[DeviceCounts] = deque()
        self.next = 0

    def read(self, ctrl, history: deque) -> DeviceCounts:
        """Enqueue a non-blocking read of ctrl[0:CTRL_WORDS] into the next row."""
        i = self.next
        self.next = (i + 1) % len(self.owner)
        old = self.owner[i]
        if old is not None:
            old.get()  # STATS_ROWS reads ago: long passed, unless the host ran that far ahead
        row = self.host[i]
        ev = self.cl.enqueue_copy(self.queue, row, ctrl, is_blocking=False)
        c = self.owner[i] = DeviceCounts(row, ev, history)
        self.pending.append(c)
        return c

    def poll(self) -> None:
        """Resolve the reads that have completed, oldest first (the queue is in order)."""
        p = self.pending
        while p and p[0].done():
            p.popleft().get()
