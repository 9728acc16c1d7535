"""Every hard case of tests/cases.py through the float64 reference: finite outputs and gradients,
the right culling (paired: bad input culled, extreme-but-valid input kept), exact agreement with a
literal per-pixel loop and a literal binning, and analytic checks."""
from __future__ import annotations

import math

import numpy as np
import pytest

import reings
from cases import (CASES, NON_FINITE_POISON, POISON_VALUES, case, make_camera, make_gaussians,
                   perf_scene)
from reings.backends import reference as ref
from reings.backends.base import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE, tile_grid
from reings.types import FIELDS, Gaussians

EXACT = 1e-12  # float64 identities (alpha + T = 1, sums of importance) hold to round-off


def _cotangents(cam, seed=0):
    rng = np.random.default_rng(seed)
    H, W = cam.height, cam.width
    return (rng.normal(size=(H, W, 3)).astype(np.float32), rng.normal(size=(H, W)).astype(np.float32),
            rng.normal(size=(H, W)).astype(np.float32))


# ------------------------------------------------------------------------------------------------
# all cases: finiteness, culling, invariants
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CASES))
def test_case_finite_and_culled_right(name):
    c = case(name)
    g, cam = c.gaussians, c.camera
    be = reings.get_backend("reference")
    out = be.render(g, cam, background=(0.1, 0.2, 0.3), want_importance=True)
    for k in ("rgb", "depth", "alpha", "final_T", "importance"):
        assert np.all(np.isfinite(getattr(out, k))), f"{name}: non-finite {k}"
    vr, vd, va = _cotangents(cam)
    gr = be.render_vjp(g, cam, vr, vd, va, background=(0.1, 0.2, 0.3))
    for f in FIELDS:
        assert np.all(np.isfinite(getattr(gr, f))), f"{name}: non-finite gradient {f}"
    proj = ref.project_fwd(g, cam)
    vis = proj.radii > 0
    if c.expect_visible is not None:
        np.testing.assert_array_equal(vis, c.expect_visible, err_msg=f"{name}: culling")
    for f in FIELDS:  # culled Gaussians get exactly zero gradient
        assert not np.any(getattr(gr, f)[~vis]), f"{name}: culled Gaussian has gradient in {f}"
    # culled rows are zero (base.py contract)
    for f in ("means2d", "conics", "depths", "colors", "opacities", "tile_rect"):
        assert not np.any(getattr(proj, f)[~vis]), f"{name}: culled row of {f} not zero"
    # float64 invariants
    _, bins, o64, stats = ref.render64(g, cam, (0.1, 0.2, 0.3), want_importance=True)
    np.testing.assert_allclose(o64.alpha + o64.final_T, 1.0, rtol=0, atol=EXACT)
    assert np.all(o64.final_T >= T_MIN), "T never drops below T_MIN (stop happens before)"
    assert math.isclose(o64.importance.sum(), o64.alpha.sum(), rel_tol=1e-12, abs_tol=EXACT)
    assert stats["visible"] == int(vis.sum()) and stats["intersections"] == len(bins.gid_from_isect)
    assert out.stats == stats


# ------------------------------------------------------------------------------------------------
# the vectorised stages against literal transcriptions of the spec
# ------------------------------------------------------------------------------------------------
def literal_bins(proj, W, H):
    tiles_x, _ = tile_grid(W, H)
    vis = [i for i in range(len(proj.radii)) if proj.radii[i] > 0]
    ranked = sorted(vis, key=lambda i: (proj.depths[i], i))
    emit = []
    for gid in ranked:
        tx0, ty0, tx1, ty1 = proj.tile_rect[gid]
        for ty in range(ty0, ty1):
            for tx in range(tx0, tx1):
                emit.append((ty * tiles_x + tx, proj.depths[gid], gid))
    order = sorted(range(len(emit)), key=lambda e: emit[e])
    return ranked, emit, order


def literal_rasterize(proj, bins, W, H, bg):
    tiles_x, _ = tile_grid(W, H)
    rgb, depth, alpha = np.zeros((H, W, 3)), np.zeros((H, W)), np.zeros((H, W))
    final_T, last = np.ones((H, W)), np.zeros((H, W), int)
    for j in range(H):
        for i in range(W):
            t = (j // TILE_SIZE) * tiles_x + i // TILE_SIZE
            s, e = bins.tile_ranges[t]
            T, C, D, A = 1.0, np.zeros(3), 0.0, 0.0
            for k in range(s, e):
                gid = bins.gid_from_isect[k]
                dx = proj.means2d[gid, 0] - (i + 0.5)
                dy = proj.means2d[gid, 1] - (j + 0.5)
                a_, b_, c_ = proj.conics[gid]
                power = -0.5 * (a_ * dx * dx + c_ * dy * dy) - b_ * dx * dy
                if power > 0:
                    continue
                al = min(ALPHA_MAX, proj.opacities[gid] * math.exp(power))
                if al < ALPHA_MIN:
                    continue
                if T * (1 - al) < T_MIN:
                    break
                C += proj.colors[gid] * al * T
                D += proj.depths[gid] * al * T
                A += al * T
                T *= 1 - al
                last[j, i] = k - s + 1
            rgb[j, i] = C + T * np.asarray(bg)
            depth[j, i], alpha[j, i], final_T[j, i] = D, A, T
    return rgb, depth, alpha, final_T, last


LITERAL_CASES = ["one", "needles", "saturated", "depth_ties", "size_70x45", "size_1x1", "size_17x15",
                 "tile_corner", "alpha_clamp", "many_in_one_tile", "rotated_camera", "offscreen_clamp"]


@pytest.mark.parametrize("name", LITERAL_CASES)
def test_bin_and_rasterize_match_literal_spec(name):
    c = case(name)
    cam, bg = c.camera, (0.2, 0.1, 0.7)
    W, H = cam.width, cam.height
    proj = ref.project_fwd(c.gaussians, cam)
    bins = ref.bin(proj, W, H)
    ranked, emit, order = literal_bins(proj, W, H)
    np.testing.assert_array_equal(bins.gid_from_rank, ranked)
    np.testing.assert_array_equal(bins.emit_from_isect, order)
    np.testing.assert_array_equal(bins.gid_from_isect, [emit[e][2] for e in order])
    counts = [(r[2] - r[0]) * (r[3] - r[1]) for r in proj.tile_rect[ranked]]
    np.testing.assert_array_equal(bins.offset_from_rank, np.concatenate([[0], np.cumsum(counts)]))
    tiles = np.array([emit[e][0] for e in order], dtype=np.int64)
    for t, (s, e) in enumerate(bins.tile_ranges):
        assert np.all(tiles[s:e] == t) and (s == e or (s == 0 or tiles[s - 1] < t))
        assert s == np.count_nonzero(tiles < t) and e == np.count_nonzero(tiles <= t)
    for a in (bins.gid_from_rank, bins.offset_from_rank, bins.gid_from_isect, bins.emit_from_isect, bins.tile_ranges):
        assert a.dtype == np.int32
    out = ref.rasterize_fwd(proj, bins, W, H, bg)
    rgb, depth, alpha, final_T, last = literal_rasterize(proj, bins, W, H, bg)
    np.testing.assert_allclose(out.rgb, rgb, rtol=0, atol=EXACT)
    np.testing.assert_allclose(out.depth, depth, rtol=0, atol=EXACT * max(1.0, np.abs(proj.depths).max()))
    np.testing.assert_allclose(out.alpha, alpha, rtol=0, atol=EXACT)
    np.testing.assert_allclose(out.final_T, final_T, rtol=0, atol=EXACT)  # numpy exp vs libm exp: ulps
    np.testing.assert_array_equal(out.last, last)


# ------------------------------------------------------------------------------------------------
# analytic checks
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("opacity", [0.3, 0.7, 0.995])
def test_one_isotropic_gaussian_on_a_pixel_centre(opacity):
    # f = 32, c = 16: mean (x, y) = (-0.5, -0.5)*z/f puts (u, v) at the centre of pixel (15, 15)
    cam = make_camera(32, 32, f=32.0, cx=16.0, cy=16.0)
    z = 4.0
    logit = math.log(opacity / (1 - opacity))
    g = make_gaussians([[-0.5 * z / 32, -0.5 * z / 32, z]], log_scales=np.full((1, 3), math.log(0.2)),
                       opacity_logits=[logit], sh=np.array([[[0.4, -0.2, 2.0]]]))
    bg = (0.25, 0.5, 0.75)
    _, _, out, _ = ref.render64(g, cam, bg)
    p32 = ref.project_fwd(g, cam)
    assert np.allclose(p32.means2d[0], [15.5, 15.5], atol=1e-6)
    o = 1 / (1 + math.exp(-float(np.float32(logit))))
    a = min(ALPHA_MAX, o)
    tz = float(np.float32(z))
    col = np.array([0.4, -0.2, 2.0], np.float32).astype(np.float64) * ref.SH_C0 + 0.5
    np.testing.assert_allclose(out.alpha[15, 15], a, rtol=1e-6)  # u is 15.5 up to float32 rounding of x
    np.testing.assert_allclose(out.depth[15, 15], tz * a, rtol=1e-6)
    np.testing.assert_allclose(out.rgb[15, 15], col * a + (1 - a) * np.array(bg), rtol=1e-6)
    np.testing.assert_allclose(out.final_T[15, 15], 1 - a, rtol=1e-6)
    assert out.last[15, 15] == 1
    # isotropy: the four pixels around are symmetric
    assert math.isclose(out.alpha[14, 15], out.alpha[16, 15], rel_tol=1e-5)
    assert math.isclose(out.alpha[15, 14], out.alpha[15, 16], rel_tol=1e-5)


def test_saturated_stack_stops_early():
    c = case("saturated")
    proj, bins, out, _ = ref.render64(c.gaussians, c.camera)
    lens = np.diff(bins.tile_ranges, axis=1)[:, 0]
    centre = (c.camera.height // 2, c.camera.width // 2)
    assert out.last[centre] < 12, "the centre pixel stops before the end of its list"
    assert out.final_T[centre] >= T_MIN and out.final_T[centre] < 1e-2
    assert lens.max() == 12


def test_depth_ties_order_by_gid():
    c = case("depth_ties")
    proj = ref.project_fwd(c.gaussians, c.camera)
    assert len(set(proj.depths.tolist())) == 1
    bins = ref.bin(proj, c.camera.width, c.camera.height)
    np.testing.assert_array_equal(bins.gid_from_rank, np.arange(5))
    for s, e in bins.tile_ranges:
        np.testing.assert_array_equal(bins.gid_from_isect[s:e], np.sort(bins.gid_from_isect[s:e]))


def test_tile_corner_covers_four_tiles():
    c = case("tile_corner")
    proj = ref.project_fwd(c.gaussians, c.camera)
    np.testing.assert_allclose(proj.means2d[0], [16.0, 16.0])
    np.testing.assert_array_equal(proj.tile_rect[0], [0, 0, 2, 2])


def test_offscreen_clamp_is_active():
    c = case("offscreen_clamp")
    _, aux = ref._project(c.gaussians, c.camera, 0.01, None)
    assert not aux["mask_x"][0] and aux["mask_y"][0]
    assert aux["mask_x"][1] and not aux["mask_y"][1]
    assert not aux["mask_x"][3] and not aux["mask_y"][3]


def test_empty_image_is_background():
    c = case("empty")
    out = reings.render(c.gaussians, c.camera, device="reference", background=(0.1, 0.2, 0.3))
    np.testing.assert_allclose(out.rgb, np.broadcast_to(np.float32([0.1, 0.2, 0.3]), out.rgb.shape))
    assert not out.alpha.any() and not out.depth.any() and np.all(out.final_T == 1)


# ------------------------------------------------------------------------------------------------
# poison values, paired: non-finite culls, extreme-but-valid stays visible
# ------------------------------------------------------------------------------------------------
POISON_SLOT = dict(means=(0, 0), quats=(0, 0), log_scales=(0, 0), opacity_logits=(0,), sh=(0, 0, 0))


def _expect_visible(field, poison):
    if poison in NON_FINITE_POISON:
        return False
    if field == "means":
        return {"+flt_max": False, "-flt_max": False, "tile": None}.get(poison, True)
    if field == "quats":  # |q|^2 overflows float32 at FLT_MAX: backends may differ -> not pinned
        return None if poison in ("+flt_max", "-flt_max") else True
    if field == "log_scales":
        return poison != "+flt_max"  # exp overflows -> culled; exp(-FLT_MAX) = 0 is still valid
    return True  # opacity logits (sigmoid saturates) and SH DC (colour clamps or stays finite)


def _poison_base():
    cam = make_camera(32, 32)
    g = make_gaussians([[0.0, 0.0, 4.0], [0.5, 0.2, 5.0], [-0.4, -0.3, 3.0]],
                       quats=[[1.0, 0.2, 0.3, -0.1]] * 3, log_scales=np.full((3, 3), np.log(0.3)), sh_degree=1)
    return g, cam


@pytest.mark.parametrize("poison", list(POISON_VALUES))
@pytest.mark.parametrize("field", list(POISON_SLOT))
def test_poison_paired(field, poison):
    g0, cam = _poison_base()
    arrays = {f: getattr(g0, f).copy() for f in FIELDS}
    arrays[field][POISON_SLOT[field]] = np.float32(POISON_VALUES[poison])
    g = Gaussians(**arrays)
    proj0, proj = ref.project_fwd(g0, cam), ref.project_fwd(g, cam)
    want = _expect_visible(field, poison)
    if want is not None:
        assert bool(proj.radii[0] > 0) == want, f"{field}={poison}: visible={proj.radii[0] > 0}, want {want}"
    for f in ("means2d", "conics", "depths", "radii", "tile_rect", "colors", "opacities"):
        np.testing.assert_array_equal(getattr(proj, f)[1:], getattr(proj0, f)[1:], err_msg=f"isolation {f}")
    be = reings.get_backend("reference")
    out = be.render(g, cam, want_importance=True)
    for k in ("rgb", "depth", "alpha", "final_T", "importance"):
        assert np.all(np.isfinite(getattr(out, k))), f"{field}={poison}: non-finite {k}"
    vr, vd, va = _cotangents(cam, 1)
    gr = be.render_vjp(g, cam, vr, vd, va)
    g64 = ref.render_vjp64(g, cam, vr, vd, va)
    # a colour near FLT_MAX is valid and renders finitely, but the true gradients of the Gaussians
    # blended with it exceed FLT_MAX: the float32 result may then be ±inf (never NaN); the float64
    # gradient is always finite.
    may_overflow = poison in ("+flt_max", "-flt_max")
    for f in FIELDS:
        assert np.all(np.isfinite(getattr(g64, f))), f"{field}={poison}: non-finite float64 gradient {f}"
        a = getattr(gr, f)
        assert not np.any(np.isnan(a)), f"{field}={poison}: NaN gradient {f}"
        assert may_overflow or np.all(np.isfinite(a)), f"{field}={poison}: non-finite gradient {f}"
        if not proj.radii[0]:
            assert not np.any(getattr(gr, f)[0]), f"{field}={poison}: culled Gaussian has gradient {f}"


# ------------------------------------------------------------------------------------------------
# API-level behaviour of the reference backend
# ------------------------------------------------------------------------------------------------
def test_opacity_override_and_grad_fields():
    c = case("rotated_camera")
    g, cam = c.gaussians, c.camera
    vr, vd, va = _cotangents(cam, 2)
    out = reings.render(g, cam, device="reference", opacity_override=0.99)
    ref_out = ref.render64(g, cam, opacity_override=0.99)[2]
    np.testing.assert_array_equal(out.alpha, ref_out.alpha.astype(np.float32))
    gr = reings.render_vjp(g, cam, vr, vd, va, device="reference", opacity_override=0.99)
    assert not gr.opacity_logits.any() and gr.means.any()
    only = reings.render_vjp(g, cam, vr, vd, va, device="reference", grad_fields=("opacity_logits",))
    full = reings.render_vjp(g, cam, vr, vd, va, device="reference")
    np.testing.assert_array_equal(only.opacity_logits, full.opacity_logits)
    for f in FIELDS:
        if f != "opacity_logits":
            assert not getattr(only, f).any()


def test_importance_is_sum_of_alpha_T():
    c = case("size_70x45")
    out = reings.render(c.gaussians, c.camera, device="reference", want_importance=True)
    assert out.importance.shape == (len(c.gaussians),) and np.all(out.importance >= 0)
    np.testing.assert_allclose(out.importance.sum(), out.alpha.sum(dtype=np.float64), rtol=1e-5)


def test_perf_scene_generator():
    g, cam = perf_scene("A", n=3000)
    g2, _ = perf_scene("A-sh3", n=3000)
    assert (cam.width, cam.height, cam.fx, cam.cx, cam.cy) == (504, 378, 420.0, 252.0, 189.0)
    assert g.sh.shape == (3000, 1, 3) and g2.sh.shape == (3000, 16, 3)
    np.testing.assert_array_equal(g.means, g2.means)  # same draws before the higher SH bands
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1.0, atol=1e-6)
    z = g.means[:, 2]
    assert z.min() >= 2 and z.max() <= 8
    vis = ref.project_fwd(g, cam).radii > 0
    assert 0.75 < vis.mean() < 0.95, vis.mean()  # docs/perf_notes.md §1.6: 82,021 / 100k visible for scene A
    with pytest.raises(ValueError):
        perf_scene("D")
