"""Rasterizer: `kernels/rasterize.cl` on one device (forward, backward, importance, isect_reduce).

Device-level API (buffers in, events out; every call enqueues on `handle.queue`, in order):

    r = Rasterizer(handle)                        # kernels built and fetched once
    r.fwd(means2d, conics, colors, opacities, depths, n,          # [N,2] [N,3] [N,3] [N] [N]
          tile_ranges, gid_from_isect, emit_from_isect, n_isect,  # [T,2] [K] [K]
          width, height, background=(0,0,0), importance=False)  -> event
        writes r.rgb [H,W,3], r.depth, r.alpha, r.final_T [H,W] float32, r.last [H,W] int32,
        r.packed [N] float16-records, and with importance=True r.imp_emit [K] (alpha*T per emit slot)
    r.bwd(tile_ranges, gid_from_isect, emit_from_isect, n_isect, width, height,
          v_rgb=None, v_depth=None, v_alpha=None)                 -> event
        reads r.packed and r.rgb/depth/final_T/last of the last `fwd` on this Rasterizer (pass
        `fwd_out=(rgb, depth, final_T, last, packed)` to use others) and writes r.v_emit [K, 10];
        opacity_only=True: only field 8 (d/d opacity) is summed, the others are written as 0, field 8
        with the bits of the full backward (RASTER_BWD_OPACITY, kernels/rasterize.cl). On CPUs the backward
        of the last `fwd` (the same bin buffers, K and size, no `prep` / `packed_for` since, no `fwd_out`)
        tests that forward's per-pair vector sets r.hits instead of each Gaussian's box (RASTER_HITS): the
        bins' contents must not change in between
    r.reduce(records, width, offset_from_rank, gid_from_rank, n_rank, out, accumulate=False,
             count=None)                                          -> event
        out[gid_from_rank[r], :] (+)= sum of records[offset_from_rank[r]:offset_from_rank[r+1], :];
        rows of `out` for gids with no rank are not touched (zero them first, or accumulate).
        count=(buffer, index): the number of ranks is the uint32 buffer[index] on the device (the
        binning's V, sync-free mode) and n_rank only bounds it (the launch size).

Buffers are the persistent `Scratch` ones (grown geometrically, never shrunk); a call's outputs stay
valid until the next call of the same kind. `Rasterizer(handle, scratch=, shared=)`: the forward's
outputs come from `scratch`, the backward's per-emit records r.v_emit from `shared` (default:
`scratch`), so that two rasterizers over two frame slots (reings/backends/opencl/backend.py) keep
their own images and share the records, which nothing reads after the `reduce` that follows.
(On Oclgrind every `Scratch` keeps the buffers it replaces alive: see
reings/backends/opencl/scratch.py.)
Host-level helpers for tests and debugging:
`rasterize_fwd_host(proj, bins, W, H, background, want_importance) -> RasterOut` and
`rasterize_bwd_host(proj, bins, W, H, v_rgb, v_depth, v_alpha, background) -> RasterGrads`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..base import TILE_SIZE, V_RECORD, Bins, Projected, RasterGrads, RasterOut, tile_grid
from .device import open_device
from .program import library_for
from .scratch import Scratch

FILE = "rasterize.cl"
TILE_PIXELS = TILE_SIZE * TILE_SIZE
PACKED_BYTES = 64  # one float16 record per Gaussian (rasterize_prep)
_BWD_TYPES = [None] * 4 + [np.int32] * 4 + [None] * 7 + [np.int32] + [None] * 4 + [np.int32]  # rasterize_bwd's scalars


def raster_vec(device=None) -> int:
    """The CPU schedule's pixel lanes (RASTER_VEC): $REINGS_RASTER_VEC (8 or 16), else 16 where the
    device's native float vector is 16 wide or more (PoCL on AVX-512), else 8.

    A pixel vector is a block of 4 x RASTER_VEC / 4 pixels (RASTER_BLOCK_H, kernels/rasterize.cl): every
    pixel gets the same values at every width and block shape, and only the sums of a tile's
    per-Gaussian records change order. On a 2-core AVX-512 Xeon (PoCL 3.0), on fern's fitted states, 16
    lanes in 4 x 4 blocks took 0.68-0.74 of the forward's and 0.80-0.81 of the backward's time of 8 lanes
    in 4 x 2 blocks (docs/perf_notes.md §27; the quality of whole runs at both widths: docs/results.md §42)."""
    import os

    env = os.environ.get("REINGS_RASTER_VEC", "").strip()
    if env:
        if env not in ("8", "16"):
            raise ValueError(f"REINGS_RASTER_VEC must be 8 or 16, got {env!r}")
        return int(env)
    return native_lanes(device)


def native_lanes(device) -> int:
    """16 where the device's native float vector is 16 wide or more (PoCL on AVX-512), else 8: the CPU
    schedule's default pixel lanes (raster_vec), SSIM's (losses.PhotometricCL) and project.cl's lanes where the
    build does not take clang's builtins (backend.proj_lanes)."""
    return 16 if int(getattr(device, "native_vector_width_float", 0) or 0) >= 16 else 8


# isect_reduce's GPU schedule: work-items per rank (>= V_RECORD) and per work-group (RED_LANES / RED_WG,
# kernels/rasterize.cl)
REDUCE_LANES, REDUCE_WG = 16, 256
# rasterize_bwd's GPU schedule: pixels per work-item (BWD_PIX, kernels/rasterize.cl; docs/perf_notes.md §28)
BWD_PIX = 1


def bwd_pix() -> int:
    """The GPU schedule's pixels per rasterize_bwd work-item (BWD_PIX): $REINGS_BWD_PIX (1, 2 or 4),
    else the default BWD_PIX."""
    import os

    env = os.environ.get("REINGS_BWD_PIX", "").strip()
    if env:
        if env not in ("1", "2", "4"):
            raise ValueError(f"REINGS_BWD_PIX must be 1, 2 or 4, got {env!r}")
        return int(env)
    return BWD_PIX


# isect_reduce's ranks per work-item on the CPU schedule (REDUCE_CHUNK, its fields as vectors): 0.46-0.50x of one rank
# per work-item with scalar fields on fern's fine / final states, 2 Xeon cores (docs/perf_notes.md §43)
REDUCE_CHUNK_CPU = 16


def _nd(n: int, local: int) -> int:
    return max(local, (n + local - 1) // local * local)


_PIXELS = (("rgb", 3), ("depth", 1), ("alpha", 1), ("final_T", 1), ("last", 1))  # Rasterizer.pixel_buffers


class Rasterizer:
    """The rasterizer kernels of one device. `cpu_schedule` overrides REINGS_CPU_SCHEDULE (tests run
    both schedules on PoCL); extra `defines` (e.g. RASTER_VEC=16, BWD_BATCH=64) go to every build;
    `scratch` holds the outputs, `shared` (default `scratch`) the backward's r.v_emit."""

    def __init__(self, handle, cpu_schedule: bool | None = None, scratch: Scratch | None = None,
                 shared: Scratch | None = None, **defines):
        import pyopencl as cl

        self.cl = cl
        self.handle = handle
        self.queue = handle.queue
        lib = library_for(handle)
        d = dict(defines)
        if cpu_schedule is not None:
            d["REINGS_CPU_SCHEDULE"] = int(bool(cpu_schedule))
        self.cpu_schedule = bool(d.get("REINGS_CPU_SCHEDULE", lib.base_defines["REINGS_CPU_SCHEDULE"]))
        if scratch is None:
            scratch = Scratch(handle)
        self.scratch = scratch
        self.shared = scratch if shared is None else shared
        if self.cpu_schedule and "RASTER_VEC" not in d:
            d["RASTER_VEC"] = raster_vec(handle.device)
        if not self.cpu_schedule:  # GPU schedule: isect_reduce's group, rasterize_bwd's pixels per work-item
            d.setdefault("RED_LANES", REDUCE_LANES)
            d.setdefault("RED_WG", REDUCE_WG)
            d.setdefault("BWD_PIX", bwd_pix())
            self.red_lanes, self.red_wg = int(d["RED_LANES"]), int(d["RED_WG"])
            if int(d["BWD_PIX"]) not in (1, 2, 4):
                raise ValueError(f"Rasterizer: BWD_PIX must be 1, 2 or 4, got {d['BWD_PIX']}")
        self._lib, self._defines = lib, d
        if self.cpu_schedule:  # isect_reduce's ranks per work-item (kernels/rasterize.cl REDUCE_CHUNK)
            d.setdefault("REDUCE_CHUNK", REDUCE_CHUNK_CPU)
        self.reduce_chunk = int(d.get("REDUCE_CHUNK", 1)) if self.cpu_schedule else 1
        if self.reduce_chunk < 1:
            raise ValueError(f"Rasterizer: REDUCE_CHUNK must be at least 1, got {self.reduce_chunk}")
        self.k_prep = lib.get(FILE, "rasterize_prep", RASTER_IMPORTANCE=0, **d)
        self.k_fwd = lib.get(FILE, "rasterize_fwd", RASTER_IMPORTANCE=0, **d)
        self.k_bwd = lib.get(FILE, "rasterize_bwd", RASTER_IMPORTANCE=0, **d)
        self.k_reduce = lib.get(FILE, "isect_reduce", RASTER_IMPORTANCE=0, **d)
        self._k_fwd_imp = None
        i32, f32 = np.int32, np.float32
        self.k_prep.set_scalar_arg_dtypes([None] * 6 + [i32])
        fwd_types = [None] * 4 + [i32] * 4 + [f32] * 3 + [None] * 7
        self.k_fwd.set_scalar_arg_dtypes(fwd_types)
        self._fwd_types = fwd_types
        self.k_bwd.set_scalar_arg_dtypes(_BWD_TYPES)
        self._k_bwd_variants: dict = {}  # RASTER_BWD_OPACITY / RASTER_BWD_DEPTH_O builds, on first use
        self.k_reduce.set_scalar_arg_dtypes([None] * 4 + [i32] * 3 + [None, i32])
        self.local = 1 if self.cpu_schedule else TILE_PIXELS
        self.bwd_local = 1 if self.cpu_schedule else TILE_PIXELS // int(d["BWD_PIX"])  # rasterize_bwd's group
        self._dummy = self.scratch.get("small", "raster_dummy", 16, 4)
        self.n = self.n_isect = self.width = self.height = 0
        # RASTER_HITS (CPU schedule): the last fwd's per-pair vector sets in r.hits, for a bwd of that fwd
        self.keeps_hits = self.cpu_schedule and int(d.get("RASTER_HITS", d.get("RASTER_CUT_MASK", 1))) != 0
        self._hits_of = None  # (tile_ranges, gid_from_isect, K, width, height) of the fwd that wrote r.hits
        self._pix_cache = None  # (width * height, the scratch's allocation count, the buffers): pixel_buffers

    # -- buffers ----------------------------------------------------------------------------
    def pixel_buffers(self) -> tuple:
        """The output images' buffers (rgb, depth, alpha, final_T, last) at the current size, looked
        up in the scratch once per size and kept until the scratch allocates again (a buffer found
        stays the one of its name until then; a launch's host time: docs/perf_notes.md §25)."""
        hw = self.width * self.height
        c = self._pix_cache
        if c is None or c[0] != hw or c[1] != self.scratch.allocations:
            bufs = tuple(self.scratch.get("pixel", "raster_" + name, hw, 4 * ch) for name, ch in _PIXELS)
            c = self._pix_cache = (hw, self.scratch.allocations, bufs)
        return c[2]

    @property
    def rgb(self):
        return self.pixel_buffers()[0]

    @property
    def depth(self):
        return self.pixel_buffers()[1]

    @property
    def alpha(self):
        return self.pixel_buffers()[2]

    @property
    def final_T(self):
        return self.pixel_buffers()[3]

    @property
    def last(self):
        return self.pixel_buffers()[4]

    @property
    def packed(self):
        return self.scratch.get("gauss", "raster_packed", self.n, PACKED_BYTES)

    def packed_for(self, n: int):
        """The records buffer of n Gaussians for a kernel that writes them itself (project_fwd): a
        later fwd(..., prepared=True) of n Gaussians reads it."""
        self.n = int(n)
        self._hits_of = None  # new records: the kept sets are of other ones
        return self.packed

    @property
    def imp_emit(self):
        return self.scratch.get("isect", "raster_imp_emit", self.n_isect, 4)

    @property
    def hits(self):
        """rasterize_fwd's set of pixel vectors past its cut tests per (tile, Gaussian) pair [K] uint32
        (RASTER_HITS, CPU schedule), which the backward of that forward walks instead of its own tests."""
        return self.scratch.get("isect", "raster_hits", self.n_isect, 4)

    @property
    def v_emit(self):
        return self.shared.get("isect", "raster_v_emit", self.n_isect, 4 * V_RECORD)

    @property
    def v_emit_o(self):
        """The records of a backward's second, opacity-only depth cotangent (bwd(v_depth_o=)): laid out
        as r.v_emit, valid until the next bwd with v_depth_o."""
        return self.shared.get("isect", "raster_v_emit_o", self.n_isect, 4 * V_RECORD)

    def prepare(self, importance: bool = False, opacity_only: bool = False, depth_o: bool = False) -> None:
        """Build now the variants a later fwd(importance=True) / bwd(opacity_only=True) / bwd(v_depth_o=)
        would build on first use (OpenCLBackend.prepare)."""
        if importance:
            self._fwd_imp_kernel()
        if opacity_only:
            self._bwd_kernel(True)
        if depth_o:
            self._bwd_kernel(False, True)

    def _fwd_imp_kernel(self):
        if self._k_fwd_imp is None:
            self._k_fwd_imp = self._lib.get(FILE, "rasterize_fwd", RASTER_IMPORTANCE=1, **self._defines)
            self._k_fwd_imp.set_scalar_arg_dtypes(self._fwd_types)
        return self._k_fwd_imp

    def _tiles(self, width, height):
        tx, ty = tile_grid(width, height)
        return tx, tx * ty

    def _range(self, width, height, local: int | None = None):
        """(global, local): a 2D range of tiles, one work-item (CPU) or 256 (GPU; rasterize_bwd
        256 / BWD_PIX) per tile."""
        tx, ty = tile_grid(width, height)
        local = self.local if local is None else local
        return (max(tx, 1) * local, max(ty, 1)), (local, 1)

    # -- kernels ----------------------------------------------------------------------------
    def prep(self, means2d, conics, colors, opacities, depths, n: int, wait_for=None):
        """rasterize_prep into r.packed (done by `fwd` unless prepared=True)."""
        self.n = int(n)
        self._hits_of = None  # new records: the kept sets are of other ones
        if self.n == 0:
            return self.cl.enqueue_marker(self.queue, wait_for=wait_for)
        return self.k_prep(self.queue, (_nd(self.n, 64),), None, means2d, conics, colors, opacities,
                           depths, self.packed, np.int32(self.n), wait_for=wait_for)

    def fwd(self, means2d, conics, colors, opacities, depths, n: int, tile_ranges, gid_from_isect,
            emit_from_isect, n_isect: int, width: int, height: int,
            background: Sequence[float] = (0.0, 0.0, 0.0), importance: bool = False,
            prepared: bool = False, wait_for=None):
        self.width, self.height, self.n_isect = int(width), int(height), int(n_isect)
        if not prepared:  # the one in-order queue runs it first: no wait list
            self.prep(means2d, conics, colors, opacities, depths, n, wait_for)
            wait_for = None
        elif int(n) != self.n:
            raise ValueError(f"Rasterizer.fwd: prepared records are of {self.n} Gaussians, not {n} (packed_for)")
        tiles_x, n_tiles = self._tiles(width, height)
        bg = [np.float32(b) for b in background]
        k = self._fwd_imp_kernel() if importance else self.k_fwd
        gid = gid_from_isect if self.n_isect else self._dummy
        emit = emit_from_isect if self.n_isect else self._dummy
        imp = self.imp_emit if importance else self._dummy
        keep = self.keeps_hits and self.n_isect > 0
        self._hits_of = None
        ev = k(self.queue, *self._range(width, height), self.packed, tile_ranges,
               gid, emit, np.int32(width), np.int32(height), np.int32(tiles_x), np.int32(n_tiles),
               *bg, *self.pixel_buffers(), imp, self.hits if keep else self._dummy, wait_for=wait_for)
        if keep:  # the sets of these bins (whose contents must not change before the backward) and size
            self._hits_of = (tile_ranges, gid_from_isect, self.n_isect, self.width, self.height)
        return ev

    def _bwd_kernel(self, opacity_only: bool, depth_o: bool = False):
        """The rasterize_bwd build: the full one, RASTER_BWD_OPACITY or RASTER_BWD_DEPTH_O (built on first use)."""
        if opacity_only and depth_o:
            raise ValueError("Rasterizer.bwd: opacity_only and v_depth_o exclude each other")
        variant = "RASTER_BWD_OPACITY" if opacity_only else "RASTER_BWD_DEPTH_O" if depth_o else None
        if variant is None:
            return self.k_bwd
        k = self._k_bwd_variants.get(variant)
        if k is None:
            k = self._lib.get(FILE, "rasterize_bwd", RASTER_IMPORTANCE=0, **{variant: 1}, **self._defines)
            k.set_scalar_arg_dtypes(_BWD_TYPES)
            self._k_bwd_variants[variant] = k
        return k

    def bwd(self, tile_ranges, gid_from_isect, emit_from_isect, n_isect: int, width: int, height: int,
            v_rgb=None, v_depth=None, v_alpha=None, fwd_out=None, wait_for=None, opacity_only: bool = False,
            v_depth_o=None):
        if (int(width), int(height)) != (self.width, self.height) and fwd_out is None:
            raise ValueError("Rasterizer.bwd: image size differs from the last fwd; pass fwd_out")
        self.n_isect = int(n_isect)
        tiles_x, n_tiles = self._tiles(width, height)
        if fwd_out is None:
            rgb, depth, _, final_T, last = self.pixel_buffers()
            packed = self.packed
        else:
            rgb, depth, final_T, last, packed = fwd_out
        mask = (1 if v_rgb is not None else 0) | (2 if v_depth is not None else 0) | (4 if v_alpha is not None else 0)
        d = self._dummy
        gid = gid_from_isect if self.n_isect else d
        emit = emit_from_isect if self.n_isect else d
        depth_o = v_depth_o is not None
        # the forward's vector sets, where this is the backward of the last fwd (its images, records and bins)
        h = self._hits_of
        use_hits = (fwd_out is None and h is not None and h[0] is tile_ranges and h[1] is gid_from_isect
                    and h[2:] == (self.n_isect, int(width), int(height)))
        return self._bwd_kernel(opacity_only, depth_o)(
            self.queue, *self._range(width, height, self.bwd_local), packed, tile_ranges,
            gid, emit, np.int32(width), np.int32(height), np.int32(tiles_x), np.int32(n_tiles),
            rgb, depth, final_T, last, v_rgb if v_rgb is not None else d,
            v_depth if v_depth is not None else d, v_alpha if v_alpha is not None else d,
            np.int32(mask), self.v_emit, v_depth_o if depth_o else d, self.v_emit_o if depth_o else d,
            self.hits if use_hits else d, np.int32(use_hits), wait_for=wait_for)

    def reduce(self, records, width: int, offset_from_rank, gid_from_rank, n_rank: int, out,
               accumulate: bool = False, wait_for=None, count=None):
        if n_rank == 0:
            return self.cl.enqueue_marker(self.queue, wait_for=wait_for)
        counts, count_at = (self._dummy, -1) if count is None else count
        if self.cpu_schedule:
            gsize, lsize = (_nd(-(-n_rank // self.reduce_chunk), 64),), None
        else:  # RED_WG // RED_LANES ranks per work-group, each over RED_LANES work-items
            if not 1 <= width <= self.red_lanes:
                raise ValueError(f"isect_reduce: record width {width} outside 1..{self.red_lanes} (RED_LANES)")
            per = self.red_wg // self.red_lanes
            gsize, lsize = (-(-n_rank // per) * self.red_wg,), (self.red_wg,)
        return self.k_reduce(self.queue, gsize, lsize, records, offset_from_rank, gid_from_rank,
                             out, np.int32(n_rank), np.int32(width), np.int32(bool(accumulate)),
                             counts, np.int32(count_at), wait_for=wait_for)


# ------------------------------------------------------------------------------------------
# host-level helpers (tests, debugging)
# ------------------------------------------------------------------------------------------
_RASTERIZERS: dict[tuple, Rasterizer] = {}


def rasterizer_for(device: str = "pocl", cpu_schedule: bool | None = None, **defines) -> Rasterizer:
    import os

    # the environment's choices (raster_vec, bwd_pix) are part of the build: a changed one gets its own
    env = tuple(os.environ.get(k, "") for k in ("REINGS_RASTER_VEC", "REINGS_BWD_PIX"))
    key = (device, cpu_schedule, tuple(sorted(defines.items())), env)
    if key not in _RASTERIZERS:
        _RASTERIZERS[key] = Rasterizer(open_device(device), cpu_schedule=cpu_schedule, **defines)
    return _RASTERIZERS[key]


def _upload(r: Rasterizer, name: str, a: np.ndarray, dtype):
    a = np.ascontiguousarray(a, dtype=dtype)
    space = "pixel" if name.startswith("v_") else "small"
    buf = r.scratch.get(space, f"host_{name}", max(a.size, 1), a.itemsize)
    if a.size:
        r.cl.enqueue_copy(r.queue, buf, a)
    return buf


def _upload_inputs(r: Rasterizer, proj: Projected, bins: Bins):
    f32, i32 = np.float32, np.int32
    n = proj.means2d.shape[0]
    bufs = {k: _upload(r, k, getattr(proj, k), f32) for k in ("means2d", "conics", "colors", "opacities", "depths")}
    for k in ("tile_ranges", "gid_from_isect", "emit_from_isect", "gid_from_rank", "offset_from_rank"):
        bufs[k] = _upload(r, k, getattr(bins, k), i32)
    return n, len(bins.gid_from_isect), bufs


def _run_fwd(r, proj, bins, width, height, background, importance):
    n, k, b = _upload_inputs(r, proj, bins)
    ev = r.fwd(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n, b["tile_ranges"],
               b["gid_from_isect"], b["emit_from_isect"], k, width, height, background, importance)
    return n, k, b, ev


def _read(r, buf, shape, dtype):
    out = np.empty(shape, dtype)
    if out.size:
        r.cl.enqueue_copy(r.queue, out, buf)
    return out


def rasterize_fwd_host(proj: Projected, bins: Bins, width: int, height: int,
                       background: Sequence[float] = (0.0, 0.0, 0.0), want_importance: bool = False,
                       device: str = "pocl", cpu_schedule: bool | None = None, **defines) -> RasterOut:
    r = rasterizer_for(device, cpu_schedule, **defines)
    n, k, b, ev = _run_fwd(r, proj, bins, width, height, background, want_importance)
    importance = None
    if want_importance:
        imp = r.scratch.get("gauss", "host_importance", max(n, 1), 4)
        r.cl.enqueue_fill_buffer(r.queue, imp, np.float32(0), 0, max(n, 1) * 4)
        r.reduce(r.imp_emit, 1, b["offset_from_rank"], b["gid_from_rank"], len(bins.gid_from_rank), imp)
        importance = _read(r, imp, (n,), np.float32)
    out = RasterOut(rgb=_read(r, r.rgb, (height, width, 3), np.float32),
                    depth=_read(r, r.depth, (height, width), np.float32),
                    alpha=_read(r, r.alpha, (height, width), np.float32),
                    final_T=_read(r, r.final_T, (height, width), np.float32),
                    last=_read(r, r.last, (height, width), np.int32), importance=importance)
    if want_importance:
        out.imp_emit = _read(r, r.imp_emit, (k,), np.float32)  # type: ignore[attr-defined]
    return out


def rasterize_bwd_host(proj: Projected, bins: Bins, width: int, height: int, v_rgb=None, v_depth=None,
                       v_alpha=None, background: Sequence[float] = (0.0, 0.0, 0.0), device: str = "pocl",
                       cpu_schedule: bool | None = None, opacity_only: bool = False, v_depth_o=None,
                       **defines) -> RasterGrads:
    """Forward then backward then isect_reduce; cotangents None count as zero; opacity_only: the
    backward of Rasterizer.bwd(opacity_only=True) (only v_opacities, the rest zero); v_depth_o: the
    backward with a second, opacity-only depth cotangent (Rasterizer.bwd(v_depth_o=)): its records
    and reduced gradients ride along as `.v_emit_o` and `.grads_o`."""
    r = rasterizer_for(device, cpu_schedule, **defines)
    n, k, b, _ = _run_fwd(r, proj, bins, width, height, background, False)
    vr = _upload(r, "v_rgb", v_rgb, np.float32) if v_rgb is not None else None
    vd = _upload(r, "v_depth", v_depth, np.float32) if v_depth is not None else None
    va = _upload(r, "v_alpha", v_alpha, np.float32) if v_alpha is not None else None
    vo = _upload(r, "v_depth_o", v_depth_o, np.float32) if v_depth_o is not None else None
    r.bwd(b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], k, width, height, vr, vd, va,
          opacity_only=opacity_only, v_depth_o=vo)

    def reduced(records) -> RasterGrads:
        g = r.scratch.get("gauss", "host_grads", max(n, 1), 4 * V_RECORD)
        r.cl.enqueue_fill_buffer(r.queue, g, np.float32(0), 0, max(n, 1) * 4 * V_RECORD)
        r.reduce(records, V_RECORD, b["offset_from_rank"], b["gid_from_rank"], len(bins.gid_from_rank), g)
        a = _read(r, g, (n, V_RECORD), np.float32)
        return RasterGrads(v_means2d=a[:, 0:2].copy(), v_conics=a[:, 2:5].copy(), v_colors=a[:, 5:8].copy(),
                           v_opacities=a[:, 8].copy(), v_depths=a[:, 9].copy())

    out = reduced(r.v_emit)
    out.v_emit = _read(r, r.v_emit, (k, V_RECORD), np.float32)  # type: ignore[attr-defined]
    if vo is not None:
        out.grads_o = reduced(r.v_emit_o)  # type: ignore[attr-defined]
        out.v_emit_o = _read(r, r.v_emit_o, (k, V_RECORD), np.float32)  # type: ignore[attr-defined]
    return out
