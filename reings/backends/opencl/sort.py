"""Our own OpenCL radix sort and exclusive prefix scan (kernels/sort.cl, kernels/scan.cl).

    sorter = RadixSort.for_handle(handle)           # once per DeviceHandle (builds on first use)
    k, v, ev = sorter.sort_pairs(keys_buf, vals_buf, n, begin_bit=0, end_bit=43, key64=True)
    keys, vals = sorter.sort_pairs_host(keys_np, vals_np, 0, 43)     # numpy in, numpy out

    # sync-free binning (docs/perf_notes.md §8): the count lives on the device, n is the capacity
    k, v, ev = sorter.sort_pairs(keys_buf, vals_buf, cap, 0, 10, count=(ctrl, 1), estimate=k_guess)

    scan = ExclusiveScan.for_handle(handle)
    total, ev = scan(in_buf, out_buf, n)            # out = exclusive prefix sum, total read back
    _, ev = scan(in_buf, out_buf, n, total_buf=counts, total_at=1, read_total=False)  # no readback

The scan, and the sort's CPU schedule and device counts, are reduce-then-scan (no work-group waits on
another: docs/perf_notes.md §4.1). A GPU-schedule sort with a host count is onesweep by default
(docs/perf_notes.md §20): radix_global_hist counts every pass's digits at once, then one radix_onesweep
launch per pass finds each block's offsets by a decoupled look-back over the lower blocks (block ids
taken in launch order from an atomic counter, so a wait is always on a running work-group): 1 + passes
launches instead of 3 per pass, at 8-bit digits and blocks of 256 x 4 pairs (REINGS_SORT_ONESWEEP=0: the
three-launch sort, 11-bit digits). Both choose their schedule per device: REINGS_CPU_SCHEDULE=1 (PoCL:
one work-item per block, few large blocks, no barriers) or 0 (GPUs: one work-group per block, local
memory). See the header comments of the two .cl files for the kernels. Every schedule, geometry and
path gives the same bits (a stable sort's output is unique).

Buffers (n elements):
    keys   [n] uint32, or uint64 with key64=True
    vals   [n] uint32 (payload; a gid or an emit slot)
Sorting is stable and looks only at bits [begin_bit, end_bit) of the key; the other bits are carried
along untouched. The passes ping-pong between the caller's buffers and scratch buffers that this
object owns (grown geometrically, never reallocated when large enough). **The input buffers are
clobbered**, and the result lies either in them or in the scratch pair: use the buffers returned,
and copy them out before the next sort_pairs call on the same RadixSort if they are the scratch pair.
With `out=(keys_out, vals_out)` the passes ping-pong between that pair and the scratch pair instead:
the inputs are only read, and the result lies in `out` (the depth order that outlives the
projection's keys: backend.py, "Depth orders").

Device counts (`count=(buf, index)`): the number of pairs is the uint32 buf[index], written on the
device by an earlier command of the queue (the binning's K), and n is only the capacity (the
buffers hold n pairs, the scratch is sized for n). Nothing is read back: the GPU schedule launches
work-groups for `estimate` pairs and loops over the virtual blocks of the real count, the CPU
schedule splits the real count among its usual number of blocks (kernels/sort.cl, "Device
counts"). The first count pairs come out the same bits as a sort of that many with a host count.

Geometry (docs/perf_notes.md §10), read once per RadixSort from its arguments, else the environment:
    REINGS_SORT_ITEMS  GPU schedule elements per work-item: 1, 2, 4, 8 or 16, or `auto` (the GPU
                       default): per sort_pairs call the largest of 8, 4, 2, 1 that launches
                       >= AUTO_GROUPS_PER_CU work-groups per compute unit for n (host count) or the
                       estimate (device count), else 1 (`auto_items`); with a device count auto never
                       makes the histogram (sized for the capacity) larger per pair than 8-bit digits'
    REINGS_SORT_WG     GPU schedule work-group size, a power of two 1..1024 (default 256)
    REINGS_SORT_ONESWEEP  0 or 1 (default 1): the GPU schedule's host-count sorts through radix_onesweep,
                       whose defaults are 8-bit digits and, under items auto, 4 elements per work-item
                       (ONESWEEP_BITS_DEFAULT, ONESWEEP_AUTO_ITEMS); a count of 2^30 or more, a device
                       count or a block over the local memory takes the three-launch path
    REINGS_SORT_BITS   widest digit per pass, 1..16. Default: 8 with onesweep; without it 11 on the GPU
                       schedule where its largest block fits the device's local memory (else 8), 8 on
                       the CPU schedule. 11 sorts
                       32 bits in 3 passes (11, 11, 10) and a 10-bit tile id in one: on an H100 a pass
                       costs ~0.055 ms of launch span whatever its width (§10). A device-count sort
                       whose width was defaulted takes at most 8 bits (its histogram is sized for the
                       capacity: bin_counts' memory bound assumes 0.5 B per pair)
Always SORT_WG * SORT_ITEMS <= 65536, and auto skips items whose block does not fit the local
memory. Any geometry gives the same bits (a stable sort's output is unique). Explicit
REINGS_SORT_ITEMS below 8, REINGS_SORT_WG below 256 or REINGS_SORT_BITS above 8 enlarge the
histogram of a device-count sort (4 * 2^bits bytes per virtual block of wg * items pairs of the
capacity) beyond what bin_counts' memory bound assumes (0.5 B/pair); so does auto at wg below 256.
"""
from __future__ import annotations

import os

import numpy as np

from . import quirks
from .bin_counts import flag_setting
from .program import library_for

_U32 = np.uint32

SORT_ITEMS_ENV, SORT_WG_ENV, SORT_BITS_ENV = "REINGS_SORT_ITEMS", "REINGS_SORT_WG", "REINGS_SORT_BITS"
SORT_ONESWEEP_ENV = "REINGS_SORT_ONESWEEP"
ONESWEEP_MAX_N = 1 << 30  # a status word holds a count in 30 bits (kernels/sort.cl, "onesweep")
# onesweep's defaults (docs/perf_notes.md §20, an H100 sweep): 8-bit digits (the look-back's status words are
# 2^bits per block: at 11 bits as many as the keys) and blocks of 256 * 4 pairs under items "auto"
ONESWEEP_BITS_DEFAULT, ONESWEEP_AUTO_ITEMS = 8, 4
# a geometry whose status words take more than this per pair (and more than the floor in all) takes the
# three-launch path; the defaults take 4 B per pair of a 32-bit key, 8 of a 64-bit one
ONESWEEP_STATUS_BYTES_PER_PAIR, ONESWEEP_STATUS_FLOOR = 16, 1 << 20
SORT_ITEMS_DEFAULT, SORT_WG_DEFAULT, SORT_BITS_DEFAULT = 8, 256, 8  # the CPU schedule's; the GPU's before §10
# the GPU schedule's defaults since docs/perf_notes.md §10 (an H100: a pass costs ~0.055 ms of launch span
# whatever its width, so fewer passes win): items auto, 11-bit digits where the local memory holds them
GPU_ITEMS_DEFAULT, GPU_BITS_DEFAULT = "auto", 11
SORT_ITEMS_CHOICES = (1, 2, 4, 8, 16)
AUTO_ITEMS = (8, 4, 2, 1)  # auto's candidates, largest first
AUTO_GROUPS_PER_CU = 2  # auto: work-groups launched per compute unit at least
HIST_BYTES_PER_PAIR = 0.5  # the default's histogram per pair of capacity (4 * 2^8 B / 2048; bin_counts)


_KERNELS: dict[tuple, object] = {}


def _kernel(handle, filename: str, name: str, scalar_dtypes: list, **defines):
    """One cl.Kernel per (context, file, kernel, defines), shared by every RadixSort / ExclusiveScan
    of that context (pyopencl warns on, and pays for, repeated retrieval)."""
    key = (id(handle.context), filename, name, tuple(sorted(defines.items())))
    k = _KERNELS.get(key)
    if k is None:
        k = _KERNELS[key] = library_for(handle).get(filename, name, **defines)
        k.set_scalar_arg_dtypes(scalar_dtypes)
    return k


def _grow(cur: int, need: int) -> int:
    """Geometric growth (1.5x) so a slowly rising n does not reallocate every call."""
    return max(need, int(cur * 1.5), 1024)


class _Scratch:
    """A device buffer that only ever grows."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.buf = None
        self.nbytes = 0

    def get(self, nbytes: int):
        import pyopencl as cl

        if self.buf is None or self.nbytes < nbytes:
            self.nbytes = _grow(self.nbytes, max(nbytes, 4))
            self.buf = cl.Buffer(self.ctx, cl.mem_flags.READ_WRITE, self.nbytes)
        return self.buf


def _cpu_schedule(handle, cpu_schedule):
    if cpu_schedule is None:
        return bool(quirks.build_defines(handle.device)["REINGS_CPU_SCHEDULE"])
    return bool(cpu_schedule)


def _blocks_cpu(cores: int, n: int, min_chunk: int, per_core: int) -> tuple[int, int]:
    """(nblocks, chunk) for the CPU schedule: about per_core blocks per core (the caller's compute
    units, read from the device once), each >= min_chunk."""
    nblocks = max(1, min(cores * per_core, -(-n // min_chunk)))
    chunk = -(-n // nblocks)
    nblocks = -(-n // chunk)  # drop trailing empty blocks
    return nblocks, chunk


def split_bits(begin_bit: int, end_bit: int, max_bits: int) -> list[tuple[int, int]]:
    """Passes (shift, pass_bits) covering [begin_bit, end_bit) with digits as even as possible,
    each at most max_bits wide: 43 bits / 8 -> 8,7,7,7,7,7; 10 bits / 8 -> 5,5."""
    total = end_bit - begin_bit
    if total <= 0:
        return []
    npass = -(-total // max_bits)
    out, shift = [], begin_bit
    for i in range(npass):
        w = total // npass + (1 if i < total % npass else 0)
        out.append((shift, w))
        shift += w
    return out


def _int_setting(value, name: str, env: str, default: int, ok, what: str) -> int:
    """`value`, else $env (unset or empty: `default`), as an int passing ok(); else a ValueError."""
    raw = value if value is not None else (os.environ.get(env) or None)
    if raw is None:
        return default
    try:
        v = int(str(raw).strip())
    except ValueError:
        v = None
    if v is None or not ok(v):
        raise ValueError(f"{name if value is not None else env} must be {what}, got {raw!r}")
    return v


def _pow2(v: int) -> bool:
    return v > 0 and v & (v - 1) == 0


def sort_items_setting(items=None, default: int | str = SORT_ITEMS_DEFAULT) -> int | str:
    """Elements per work-item of the GPU schedule: `items`, else $REINGS_SORT_ITEMS, else `default`;
    "auto" or one of SORT_ITEMS_CHOICES."""
    raw = items if items is not None else (os.environ.get(SORT_ITEMS_ENV) or None)
    if raw is None:
        return default
    if isinstance(raw, str) and raw.strip().lower() == "auto":
        return "auto"
    return _int_setting(items, "items", SORT_ITEMS_ENV, SORT_ITEMS_DEFAULT, lambda v: v in SORT_ITEMS_CHOICES,
                        "'auto' or one of " + ", ".join(map(str, SORT_ITEMS_CHOICES)))


def sort_wg_setting(wg=None) -> int:
    """Work-group size of the GPU schedule: `wg`, else $REINGS_SORT_WG, else 256; a power of two <= 1024."""
    return _int_setting(wg, "wg", SORT_WG_ENV, SORT_WG_DEFAULT, lambda v: _pow2(v) and v <= 1024,
                        "a power of two in 1..1024")


def sort_bits_setting(max_bits=None, default: int = SORT_BITS_DEFAULT) -> int:
    """Widest digit per pass: `max_bits`, else $REINGS_SORT_BITS, else `default`; 1..16."""
    return _int_setting(max_bits, "max_bits", SORT_BITS_ENV, default, lambda v: 1 <= v <= 16,
                        "an integer in 1..16")


def bits_given(max_bits=None) -> bool:
    """Whether the digit width was chosen (an argument or $REINGS_SORT_BITS) rather than defaulted."""
    return max_bits is not None or bool(os.environ.get(SORT_BITS_ENV))


def auto_items(n: int, wg: int, compute_units: int, groups_per_cu: int = AUTO_GROUPS_PER_CU,
               choices: tuple = AUTO_ITEMS) -> int:
    """auto's elements per work-item for a sort of about n pairs: the largest of `choices` whose
    blocks of wg * items pairs number >= groups_per_cu * compute_units, else the smallest choice."""
    want = groups_per_cu * max(1, int(compute_units))
    for items in sorted(choices, reverse=True):
        if -(-int(n) // (wg * items)) >= want:
            return items
    return min(choices)


def sort_local_bytes(wg: int, items: int, max_bits: int) -> int:
    """Local memory of the GPU schedule's largest kernel (radix_scatter: ent, tmp, dbase, dstart)."""
    return 4 * (2 * wg * items + wg + 2 * (1 << max_bits))


def onesweep_local_bytes(wg: int, items: int, max_bits: int) -> int:
    """Local memory of radix_onesweep: radix_scatter's, the block's digit counts and its block id."""
    return sort_local_bytes(wg, items, max_bits) + 4 * (1 << max_bits) + 4


def sort_onesweep_setting(onesweep=None) -> bool:
    """Whether a GPU-schedule sort with a host count takes 1 + passes launches (radix_global_hist,
    then radix_onesweep per pass) instead of three per pass: `onesweep`, else $REINGS_SORT_ONESWEEP
    (0 or 1), else on."""
    return flag_setting(onesweep, "onesweep", SORT_ONESWEEP_ENV)


def _pass_output(i: int, npass: int, inp: tuple, tmp: tuple, out) -> tuple:
    """The (keys, vals) buffers pass i of npass writes: without `out` the scratch pair, the inputs, the
    scratch pair, ...; with `out` ..., out, scratch, out (the last pass writes out, none the inputs)."""
    if out is None:
        return tmp if i % 2 == 0 else inp
    return tuple(out) if (npass - 1 - i) % 2 == 0 else tmp


class ExclusiveScan:
    """Exclusive prefix sum of uint32 on the device: out[i] = sum(in[:i]) mod 2^32.

    __call__(in_buf, out_buf, n, total_buf=None, total_at=0, read_total=True, wait_for=None)
        in_buf, out_buf  [n] uint32 (may be the same buffer)
        total_buf        optional [>= total_at + 1] uint32 device buffer that receives the total
                         (so a caller can fold it into its one readback); default: own scratch
        returns (total or None, event); total is read back (a host sync) only if read_total.
    Two launches (scan_reduce, scan_add; kernels/scan.cl). A kernel that can write the block sums
    itself (bin.cl's bin_count) takes the block geometry from `blocks(n)` and the sums buffer from
    `block_sums(nblocks)`, and then calls `add` alone: one launch.
    Built once per DeviceHandle: `ExclusiveScan.for_handle(handle)` caches one.
    """

    _cache: dict[int, "ExclusiveScan"] = {}

    @classmethod
    def for_handle(cls, handle) -> "ExclusiveScan":
        s = cls._cache.get(id(handle))
        if s is None:
            s = cls._cache[id(handle)] = cls(handle)
        return s

    def __init__(self, handle, cpu_schedule: bool | None = None, wg: int = 256, items: int = 8,
                 blocks_per_core: int = 4):
        self.handle = handle
        self.cpu = _cpu_schedule(handle, cpu_schedule)
        self.wg, self.items, self.per_core = wg, items, blocks_per_core
        self.compute_units = max(1, int(handle.device.max_compute_units))  # a driver query: once
        self.defines = {"REINGS_CPU_SCHEDULE": int(self.cpu)}  # a block-sum writer builds with these too
        if not self.cpu:
            self.defines.update(SCAN_WG=wg, SCAN_ITEMS=items)
        u, b = np.uint32, None  # b: a buffer argument
        self.k_reduce = _kernel(handle, "scan.cl", "scan_reduce", [b, u, u, b], **self.defines)
        self.k_add = _kernel(handle, "scan.cl", "scan_add", [b, b, u, u, b, b, u], **self.defines)
        self._sums = _Scratch(handle.context)
        self._total = _Scratch(handle.context)

    def blocks(self, n: int) -> tuple[int, int, int, int]:
        """The blocks of a scan of n > 0 elements: (nblocks, chunk, global size, local size). CPU
        schedule: a work-item per block of `chunk` elements; GPU: a work-group of `wg` per block of
        wg * items elements (chunk 0)."""
        if self.cpu:
            nblocks, chunk = _blocks_cpu(self.compute_units, n, 4096, self.per_core)
            return nblocks, chunk, nblocks, 1
        nblocks = -(-n // (self.wg * self.items))
        return nblocks, 0, nblocks * self.wg, self.wg

    def block_sums(self, nblocks: int):
        """The block sums' buffer (this scan's scratch; valid until the next scan)."""
        return self._sums.get(4 * nblocks)

    def add(self, in_buf, out_buf, n: int, sums, total_buf, total_at: int, wait_for=None):
        """scan_add of n > 0 elements whose block sums (`blocks(n)`'s blocks) are in `sums`: the scan
        into out_buf, the total into total_buf[total_at]. Returns the event."""
        _, chunk, gsize, lsize = self.blocks(n)
        return self.k_add(self.handle.queue, (gsize,), (lsize,), in_buf, out_buf, n, chunk, sums, total_buf,
                          total_at, wait_for=wait_for)

    def __call__(self, in_buf, out_buf, n: int, total_buf=None, total_at: int = 0,
                 read_total: bool = True, wait_for=None):
        import pyopencl as cl

        q = self.handle.queue
        if total_buf is None:
            total_buf, total_at = self._total.get(4), 0
        if n == 0:
            ev = cl.enqueue_fill_buffer(q, total_buf, np.uint32(0), 4 * total_at, 4, wait_for=wait_for)
        else:
            nblocks, chunk, gsize, lsize = self.blocks(n)
            sums = self.block_sums(nblocks)
            self.k_reduce(q, (gsize,), (lsize,), in_buf, n, chunk, sums, wait_for=wait_for)
            ev = self.add(in_buf, out_buf, n, sums, total_buf, total_at)
        if not read_total:
            return None, ev
        t = np.empty(1, _U32)
        cl.enqueue_copy(q, t, total_buf, src_offset=4 * total_at, wait_for=[ev])
        return int(t[0]), ev

    def host(self, x: np.ndarray) -> tuple[np.ndarray, int]:
        """numpy convenience: (exclusive scan of x as uint32, total)."""
        import pyopencl as cl

        x = np.ascontiguousarray(x, dtype=_U32)
        n = x.size
        ctx, q = self.handle.context, self.handle.queue
        buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x) if n else None
        total, ev = self(buf, buf, n)
        out = np.empty(n, _U32)
        if n:
            cl.enqueue_copy(q, out, buf, wait_for=[ev])
        return out, total


class RadixSort:
    """Stable LSD radix sort of (key, value) pairs on one device (see the module docstring).

    Built once per DeviceHandle (`RadixSort.for_handle(handle)` caches one); programs for uint32
    and uint64 keys are built lazily on first use.

    cpu_schedule  None: from the device (REINGS_CPU_SCHEDULE); True/False force a schedule
    max_bits      widest digit per pass (None: $REINGS_SORT_BITS, else the schedule's default: 8 with
                  onesweep; without it 11 on the GPU schedule where its largest block fits the local
                  memory, else 8; 8 on the CPU's. A sort that onesweep leaves to the three-launch path
                  keeps this width: 4 passes of a 32-bit key at 8 bits)
    wg, items     GPU schedule work-group size and elements per work-item (block = wg * items);
                  None: $REINGS_SORT_WG / $REINGS_SORT_ITEMS, else 256 / "auto" (chosen per
                  sort_pairs call: `launch_items`; module docstring, "Geometry")
    blocks_per_core  CPU schedule: blocks (work-items) per compute unit
    onesweep      GPU schedule, host count: a pass in one launch after one histogram launch for
                  every pass (kernels/sort.cl, "onesweep"); None: $REINGS_SORT_ONESWEEP, else on.
                  The same bits either way
    """

    _cache: dict[int, "RadixSort"] = {}

    @classmethod
    def for_handle(cls, handle) -> "RadixSort":
        s = cls._cache.get(id(handle))
        if s is None:
            s = cls._cache[id(handle)] = cls(handle)
        return s

    def __init__(self, handle, cpu_schedule: bool | None = None, max_bits: int | None = None,
                 wg: int | None = None, items: int | str | None = None, blocks_per_core: int = 4,
                 onesweep: bool | None = None):
        self.handle = handle
        self.cpu = _cpu_schedule(handle, cpu_schedule)
        self.onesweep = sort_onesweep_setting(onesweep) and not self.cpu
        self.local_mem = int(handle.device.local_mem_size)
        self.wg = sort_wg_setting(wg)
        max_wg = int(getattr(handle.device, "max_work_group_size", self.wg))
        if not self.cpu and self.wg > max_wg:
            raise ValueError(f"sort geometry: work-group size {self.wg} > the device's {max_wg} "
                             f"(lower {SORT_WG_ENV})")
        self.items = sort_items_setting(items, SORT_ITEMS_DEFAULT if self.cpu else GPU_ITEMS_DEFAULT)
        if self.items != "auto" and self.wg * self.items > 65536:
            raise ValueError(f"sort geometry: wg * items = {self.wg} * {self.items} > 65536")
        # the default digit: the GPU schedule's 11 bits where its largest block fits the local memory
        # (auto's largest items), else 8 (e.g. Oclgrind's 32 KiB); the CPU schedule's 8
        biggest = max(AUTO_ITEMS) if self.items == "auto" else self.items
        gpu_bits = GPU_BITS_DEFAULT if sort_local_bytes(self.wg, biggest, GPU_BITS_DEFAULT) <= self.local_mem \
            else SORT_BITS_DEFAULT
        if self.onesweep:
            gpu_bits = ONESWEEP_BITS_DEFAULT
        self.max_bits = sort_bits_setting(max_bits, SORT_BITS_DEFAULT if self.cpu else gpu_bits)
        # a device-count sort sizes its histogram for the capacity (bin_counts' memory bound assumes the
        # 8-bit digit's 0.5 B per pair): a defaulted wider digit is cut to 8 bits there
        self.bits_given = bits_given(max_bits)
        self.per_core = blocks_per_core
        self.compute_units = max(1, int(handle.device.max_compute_units))  # auto's rule (tests fake it)
        self._kernels: dict[tuple, tuple] = {}
        ctx = handle.context
        self._keys_tmp, self._vals_tmp = _Scratch(ctx), _Scratch(ctx)
        self._hist, self._totals = _Scratch(ctx), _Scratch(ctx)
        self._no_count = _Scratch(ctx)  # the counts argument of a host-count sort (never read)
        # onesweep: the passes' status words and block-id counters; two global histograms used in
        # turn (each sort's radix_global_hist adds into one and zeroes the other for the next sort)
        self._status, self._ids = _Scratch(ctx), _Scratch(ctx)
        self._ghist: list = []
        self._ghist_turn = 0

    def kernels(self, key64: bool, items: int | None = None, bits: int | None = None):
        """(radix_hist, radix_scan, radix_scatter), built on first use per (key64, items, wg, max_bits)
        (the CPU schedule has no items nor wg). items None: the fixed items, under auto the largest;
        bits None: max_bits (a device-count sort's kernels take `call_bits`: RADIX_BITS sizes the
        local histogram)."""
        bits = int(bits or self.max_bits)
        if self.cpu:
            key = (bool(key64), None, None, bits)
        else:
            items = int(items or (self.items if self.items != "auto" else max(AUTO_ITEMS)))
            key = (bool(key64), items, self.wg, bits)
        ks = self._kernels.get(key)
        if ks is None:
            defines = {"REINGS_CPU_SCHEDULE": int(self.cpu), "KEY64": int(key64), "RADIX_BITS": bits}
            if not self.cpu:
                need = sort_local_bytes(self.wg, items, bits)
                if need > self.local_mem:
                    raise ValueError(f"sort geometry wg={self.wg} items={items} bits={bits} needs {need} B "
                                     f"of local memory, the device has {self.local_mem}: lower {SORT_BITS_ENV} "
                                     f"or {SORT_ITEMS_ENV}")
                defines.update(SORT_WG=self.wg, SORT_ITEMS=items)
            u, b, h = np.uint32, None, self.handle  # b: a buffer argument
            i = np.int32  # count_at
            ks = self._kernels[key] = (
                _kernel(h, "sort.cl", "radix_hist", [b, u, u, u, u, b, b, i], **defines),
                _kernel(h, "sort.cl", "radix_scan", [b, u, u, b, b, i], **defines),
                _kernel(h, "sort.cl", "radix_scatter", [b, b, b, b, u, u, u, u, b, b, b, i], **defines),
            )
        return ks

    def onesweep_kernels(self, key64: bool, items: int, bits: int):
        """(radix_global_hist, radix_onesweep) of the GPU schedule, built on first use (`kernels`'
        defines, and OS_ATOMIC_STATUS=1 where `quirks.volatile_status_words` is false)."""
        key = ("onesweep", bool(key64), int(items), self.wg, int(bits))
        ks = self._kernels.get(key)
        if ks is None:
            defines = {"REINGS_CPU_SCHEDULE": 0, "KEY64": int(key64), "RADIX_BITS": int(bits),
                       "SORT_WG": self.wg, "SORT_ITEMS": int(items)}
            if not quirks.volatile_status_words(self.handle.device):
                defines["OS_ATOMIC_STATUS"] = 1  # kernels/sort.cl: the look-back through atomics
            u, b, h = np.uint32, None, self.handle
            ks = self._kernels[key] = (
                _kernel(h, "sort.cl", "radix_global_hist", [b, u, u, u, u, b, b, u, b, u, b], **defines),
                _kernel(h, "sort.cl", "radix_onesweep", [b, b, b, b, u, u, u, u, b, b, u, b], **defines),
            )
        return ks

    def warm(self, key64: bool) -> None:
        """Retrieve (and build on first use) the kernels a sort of this sorter takes by default: the
        three-launch ones (device counts) and, with onesweep, radix_global_hist / radix_onesweep at
        auto's items, so that the first sort of a fit compiles nothing."""
        self.kernels(key64)
        items = ONESWEEP_AUTO_ITEMS if self.items == "auto" else self.items
        if self.uses_onesweep(1 << 20, items, self.max_bits, False):
            self.onesweep_kernels(key64, items, self.max_bits)

    def uses_onesweep(self, n: int, items: int, bits: int, device_count: bool, npass: int | None = None) -> bool:
        """Whether a sort of n pairs goes through radix_onesweep: the GPU schedule with it on, a host
        count below 2^30, the kernel's local memory within the device's, and (given the passes) the
        status words within 2^31 and within ONESWEEP_STATUS_BYTES_PER_PAIR per pair or
        ONESWEEP_STATUS_FLOOR in all (a small block at a wide digit would take more status than
        keys: `status_words`)."""
        if not (self.onesweep and not device_count and n < ONESWEEP_MAX_N
                and onesweep_local_bytes(self.wg, items, bits) <= self.local_mem):
            return False
        if npass is None:
            return True
        words = self.status_words(n, items, npass, bits)
        return words < 2**31 and 4 * words <= max(ONESWEEP_STATUS_BYTES_PER_PAIR * n, ONESWEEP_STATUS_FLOOR)

    def status_words(self, n: int, items: int, npass: int, widest: int) -> int:
        """radix_onesweep's status words for n pairs: npass x blocks x 2^widest digit."""
        return npass * -(-n // (self.wg * items)) * (1 << widest)

    def _ghist_pair(self, words: int):
        """(this sort's global histogram, the next sort's), both of `words` uint32; zeroed once when
        made, then by radix_global_hist (kernels/sort.cl). The caller flips `_ghist_turn` once its
        radix_global_hist is enqueued (a failure before that leaves both buffers as they were)."""
        import pyopencl as cl

        if not self._ghist or self._ghist[0].size < 4 * words:
            q = self.handle.queue
            self._ghist = [cl.Buffer(self.handle.context, cl.mem_flags.READ_WRITE, 4 * words) for _ in range(2)]
            zeros = np.zeros(words, _U32)  # a copy, not a fill: Oclgrind's uninitialized check takes it as written
            for g in self._ghist:
                cl.enqueue_copy(q, g, zeros)
            self._ghist_turn = 0
        cur = self._ghist_turn
        return self._ghist[cur], self._ghist[cur ^ 1]

    def call_bits(self, device_count: bool) -> int:
        """The widest digit of one sort: max_bits, but at most 8 for a device-count sort whose width
        was defaulted (its histogram is sized for the capacity; module docstring)."""
        if device_count and not self.bits_given:
            return min(self.max_bits, SORT_BITS_DEFAULT)
        return self.max_bits

    def launch_items(self, n: int, device_count: bool = False) -> int:
        """SORT_ITEMS of a GPU-schedule sort of about n pairs (n: the host count, or a device count's
        estimate): the fixed items, or under auto ONESWEEP_AUTO_ITEMS for a sort that goes through
        radix_onesweep (`uses_onesweep`), else auto's rule (`auto_items` on this device's compute
        units); with a device_count, auto keeps the histogram within HIST_BYTES_PER_PAIR of the
        capacity (at most the largest auto choice)."""
        if self.items != "auto":
            return self.items
        bits = self.call_bits(device_count)
        if self.uses_onesweep(n, ONESWEEP_AUTO_ITEMS, bits, device_count):
            return ONESWEEP_AUTO_ITEMS
        fits = tuple(c for c in AUTO_ITEMS if sort_local_bytes(self.wg, c, bits) <= self.local_mem) or (1,)
        items = auto_items(n, self.wg, self.compute_units, choices=fits)
        if device_count:
            floor = min(max(fits), -(-int(4 * (1 << bits) / HIST_BYTES_PER_PAIR) // self.wg))
            items = max(items, next(c for c in sorted(fits) if c >= floor))
        return items

    def geometry(self, n: int, items: int | None = None) -> tuple[int, int]:
        """(nblocks, chunk): blocks per pass and elements per block (items None: `launch_items(n)`)."""
        if self.cpu:
            return _blocks_cpu(self.compute_units, n, 1024, self.per_core)
        block = self.wg * (items or self.launch_items(n))
        return -(-n // block), block

    def device_geometry(self, capacity: int, estimate: int, items: int | None = None) -> tuple[int, int]:
        """(blocks launched, virtual blocks the histogram holds) of a sort with a device count of
        at most `capacity` pairs, launched for `estimate` of them (module docstring); items None:
        `launch_items(estimate, device_count=True)`, as sort_pairs chooses them."""
        if self.cpu:
            nblocks = self.compute_units * self.per_core
            return nblocks, nblocks
        block = self.wg * (items or self.launch_items(estimate, device_count=True))
        cap_blocks = max(1, -(-capacity // block))
        return max(1, min(-(-estimate // block), cap_blocks)), cap_blocks

    def sort_pairs(self, keys_buf, vals_buf, n: int, begin_bit: int = 0, end_bit: int | None = None,
                   key64: bool = False, wait_for=None, count=None, estimate: int | None = None, out=None):
        """Sort n pairs by key bits [begin_bit, end_bit); returns (keys_out, vals_out, event).

        keys_buf  [n] uint32 (uint64 if key64)   vals_buf [n] uint32   -- both clobbered (unless out)
        count     None, or (buffer, index): the number of pairs is the uint32 buffer[index] on the
                  device, at most n, which is then the capacity (module docstring, "Device counts")
        estimate  with count: the launch geometry's guess of the count (default n)
        out       None, or (keys, vals) buffers of n pairs: the result goes there and the inputs
                  are only read (module docstring); a host count only
        The returned buffers are `out`, or either the inputs or this object's scratch pair; event is
        the last enqueued command (None if nothing was enqueued: n <= 1 with a host count, or an
        empty bit range, and no `out`).
        """
        import pyopencl as cl

        if end_bit is None:
            end_bit = 64 if key64 else 32
        if not (0 <= begin_bit <= end_bit <= (64 if key64 else 32)):
            raise ValueError(f"bad bit range [{begin_bit}, {end_bit}) for {'64' if key64 else '32'}-bit keys")
        if out is not None and count is not None:
            raise ValueError("sort_pairs: out= takes a host count")
        bits = self.call_bits(count is not None)
        passes = split_bits(begin_bit, end_bit, bits)
        ksize = 8 if key64 else 4
        if (n <= 1 and count is None) or not passes:
            if out is not None:  # nothing to sort: the pairs as they are
                ev = None
                for src, dst, size in ((keys_buf, out[0], ksize), (vals_buf, out[1], 4)):
                    if n:
                        ev = cl.enqueue_copy(self.handle.queue, dst, src, byte_count=size * n, wait_for=wait_for)
                return out[0], out[1], ev
            ev = cl.enqueue_marker(self.handle.queue, wait_for=wait_for) if wait_for else None
            return keys_buf, vals_buf, ev
        if n >= 2**32:
            raise ValueError("n must be < 2^32")
        est = n if count is None or estimate is None else int(estimate)
        items = None if self.cpu else self.launch_items(est, device_count=count is not None)  # once per call
        if not self.cpu and self.uses_onesweep(n, items, bits, count is not None, len(passes)):
            return self._sort_onesweep(keys_buf, vals_buf, n, begin_bit, end_bit, key64, passes, items, bits,
                                       wait_for, out)
        hist_k, scan_k, scat_k = self.kernels(key64, items, bits)
        q = self.handle.queue
        if count is None:
            nblocks, chunk = self.geometry(n, items)
            hist_blocks, counts, count_at = nblocks, None, np.int32(-1)
        else:
            nblocks, hist_blocks = self.device_geometry(n, est, items)
            chunk, (counts, count_at) = 0, (count[0], np.int32(count[1]))
        maxbins = 1 << max([w for _, w in passes])
        kt = self._keys_tmp.get(n * ksize)
        vt = self._vals_tmp.get(n * 4)
        hist = self._hist.get(4 * maxbins * hist_blocks)
        totals = self._totals.get(4 * maxbins)
        counts = self._no_count.get(4) if counts is None else counts
        src = inp = (keys_buf, vals_buf)
        if self.cpu:
            g, l = (nblocks,), (1,)
        else:
            g, l = (nblocks * self.wg,), (self.wg,)
        ev = None
        for i, (shift, w) in enumerate(passes):
            dst = _pass_output(i, len(passes), inp, (kt, vt), out)
            nbins = 1 << w
            hist_k(q, g, l, src[0], n, chunk, shift, nbins, hist, counts, count_at, wait_for=wait_for)
            wait_for = None
            if not self.cpu:
                scan_k(q, (nbins * self.wg,), (self.wg,), hist, n, nbins, totals, counts, count_at)
            ev = scat_k(q, g, l, src[0], src[1], dst[0], dst[1], n, chunk, shift, nbins, hist, totals,
                        counts, count_at)
            src = dst
        return src[0], src[1], ev

    def _sort_onesweep(self, keys_buf, vals_buf, n: int, begin_bit: int, end_bit: int, key64: bool, passes: list,
                       items: int, bits: int, wait_for, out):
        """sort_pairs through radix_global_hist and one radix_onesweep per pass (1 + passes launches;
        the buffers' roles as in sort_pairs)."""
        gh_k, os_k = self.onesweep_kernels(key64, items, bits)
        q = self.handle.queue
        ksize = 8 if key64 else 4
        nvb = -(-n // (self.wg * items))
        widest = max(w for _, w in passes)
        stride = 1 << widest
        npass = len(passes)
        status_words = self.status_words(n, items, npass, widest)
        ghist_words = -(-64 // bits) << bits  # the most passes of any sort here, at RADIX = 2^bits
        ghist, ghist_next = self._ghist_pair(ghist_words)
        status = self._status.get(4 * status_words)
        ids = self._ids.get(4 * npass)
        kt = self._keys_tmp.get(n * ksize)
        vt = self._vals_tmp.get(n * 4)
        g, l = (nvb * self.wg,), (self.wg,)
        gh_k(q, g, l, keys_buf, n, begin_bit, end_bit, npass, ghist, ghist_next, ghist_words, status,
             status_words, ids, wait_for=wait_for)
        self._ghist_turn ^= 1  # only once radix_global_hist is enqueued: it zeroes ghist_next
        src = inp = (keys_buf, vals_buf)
        ev = None
        for i, (shift, w) in enumerate(passes):
            dst = _pass_output(i, npass, inp, (kt, vt), out)
            ev = os_k(q, g, l, src[0], src[1], dst[0], dst[1], n, shift, 1 << w, i, ghist, status, stride, ids)
            src = dst
        return src[0], src[1], ev

    def sort_pairs_host(self, keys: np.ndarray, vals: np.ndarray | None = None, begin_bit: int = 0,
                        end_bit: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """numpy convenience: keys [n] uint32/uint64, vals [n] uint32 (default arange) -> sorted
        (keys, vals) copies. Uploads, sorts, reads back (one sync)."""
        import pyopencl as cl

        keys = np.ascontiguousarray(keys)
        if keys.dtype not in (np.uint32, np.uint64):
            raise TypeError(f"keys must be uint32 or uint64, got {keys.dtype}")
        key64 = keys.dtype == np.uint64
        n = keys.size
        vals = np.arange(n, dtype=_U32) if vals is None else np.ascontiguousarray(vals, dtype=_U32)
        if vals.shape != keys.shape:
            raise ValueError("keys and vals must have the same shape")
        if n == 0:
            return keys.copy(), vals.copy()
        ctx, q = self.handle.context, self.handle.queue
        mf = cl.mem_flags
        kb = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=keys)
        vb = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=vals)
        ko, vo, ev = self.sort_pairs(kb, vb, n, begin_bit, end_bit, key64=key64)
        ok, ov = np.empty_like(keys), np.empty_like(vals)
        cl.enqueue_copy(q, ok, ko, wait_for=[ev] if ev else None)
        cl.enqueue_copy(q, ov, vo)
        q.finish()
        return ok, ov
