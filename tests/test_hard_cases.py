"""Every hard case of tests/cases.py (and every POISON_VALUES entry) through the fused OpenCL path.

Each case: no NaN/Inf in any output or gradient; the culling the case pins (`expect_visible`) and
the reference's culling; forward and gradients against the float64 reference with the tolerances
and discontinuity band of test_render; culled Gaussians get exactly zero gradient; exact depth ties
give the reference's bins, bit for bit.
"""
from __future__ import annotations

import numpy as np
import pytest

from cases import CASES, NON_FINITE_POISON, POISON_VALUES, case, make_camera, make_gaussians
from test_bin import BINS_FIELDS
from test_render import BG, check_render, check_vjp, cotangents

from reings.backends import get_backend
from reings.backends import reference as ref
from reings.types import FIELDS, Gaussians


@pytest.mark.parametrize("name", list(CASES))
def test_case_render(device, name):
    c = case(name)
    g, cam = c.gaussians, c.camera
    be = get_backend(device)
    out, o64, band = check_render(device, g, cam, name=name)
    proj = be.project_fwd(g, cam)
    vis = proj.radii > 0
    if c.expect_visible is not None:
        np.testing.assert_array_equal(vis, c.expect_visible, err_msg=f"{name}: culling")
    np.testing.assert_array_equal(vis, ref.project_fwd(g, cam).radii > 0, err_msg=f"{name}: culling vs reference")
    if len(g) == 0:
        return
    dev, _ = check_vjp(device, g, cam, name=name)
    for f in FIELDS:
        assert not np.any(getattr(dev, f)[~vis]), f"{name}: culled Gaussian has gradient {f}"


@pytest.mark.parametrize("name", ["depth_ties", "saturated", "many_in_one_tile", "size_70x45"])
def test_case_bins_identical(device, name):
    """The device's own projection, binned on the device, gives the reference's bins exactly."""
    c = case(name)
    be = get_backend(device)
    p = be.project_fwd(c.gaussians, c.camera)
    dev = be.bin(p, c.camera.width, c.camera.height)
    exp = ref.bin(ref.project_fwd(c.gaussians, c.camera), c.camera.width, c.camera.height)
    for f in BINS_FIELDS:
        np.testing.assert_array_equal(getattr(dev, f), getattr(exp, f), err_msg=f"{name}: {f}")


POISON_SLOT = dict(means=(0, 0), quats=(0, 0), log_scales=(0, 0), opacity_logits=(0,), sh=(0, 0, 0))


def _poisoned(field, poison):
    cam = make_camera(32, 32)
    g0 = make_gaussians([[0.0, 0.0, 4.0], [0.5, 0.2, 5.0], [-0.4, -0.3, 3.0]],
                        quats=[[1.0, 0.2, 0.3, -0.1]] * 3, log_scales=np.full((3, 3), np.log(0.3)), sh_degree=1)
    arrays = {f: getattr(g0, f).copy() for f in FIELDS}
    arrays[field][POISON_SLOT[field]] = np.float32(POISON_VALUES[poison])
    return Gaussians(**arrays), cam


@pytest.mark.parametrize("poison", list(POISON_VALUES))
@pytest.mark.parametrize("field", list(POISON_SLOT))
def test_poison_project_bwd_overflow(device, field, poison):
    """The reference's rasterizer cotangents (float32: overflowing ones become +-inf) through the
    device's project_bwd: +-inf allowed where the float64 gradient exceeds FLT_MAX, NaN never."""
    g, cam = _poisoned(field, poison)
    p = ref.project_fwd(g, cam)
    vr, vd, va = cotangents(cam, 1)
    with np.errstate(all="ignore"):
        gr = ref.rasterize_bwd(p, ref.bin(p, 32, 32), None, vr, vd, va, 32, 32)
        exp = ref.project_bwd(g, cam, p, gr)
    dev = get_backend(device).project_bwd(g, cam, p, gr)
    for f in FIELDS:
        a, e = getattr(dev, f), getattr(exp, f)
        assert not np.any(np.isnan(a)), f"{field}={poison}: NaN gradient {f}"
        big = np.abs(e) > 1e37  # near or beyond the float32 range: +-inf allowed
        assert np.all(np.isfinite(a) | big), f"{field}={poison}: {f} overflowed where the reference is small"


@pytest.mark.parametrize("poison", list(POISON_VALUES))
@pytest.mark.parametrize("field", list(POISON_SLOT))
def test_poison_render(device, field, poison):
    """sh=+flt_max: a colour near FLT_MAX. Its own and its neighbours' true gradients exceed FLT_MAX;
    rasterize_bwd reruns such tiles with exactly scaled values (kernels/rasterize.cl, "Overflow") and
    isect_reduce re-sums overflowed rows the same way, so they come out +-inf or finite, never NaN."""
    g, cam = _poisoned(field, poison)
    be = get_backend(device)
    out = be.render(g, cam, background=BG, want_importance=True)
    for k in ("rgb", "depth", "alpha", "final_T", "importance"):
        assert np.all(np.isfinite(getattr(out, k))), f"{field}={poison}: non-finite {k}"
    vis = be.project_fwd(g, cam).radii > 0
    if poison in NON_FINITE_POISON:
        assert not vis[0]
    vr, vd, va = cotangents(cam, 1)
    gr = be.render_vjp(g, cam, vr, vd, va, background=BG)
    may_overflow = poison in ("+flt_max", "-flt_max")  # see test_reference_cases.test_poison_paired
    for f in FIELDS:
        a = getattr(gr, f)
        assert not np.any(np.isnan(a)), f"{field}={poison}: NaN gradient {f}"
        assert may_overflow or np.all(np.isfinite(a)), f"{field}={poison}: non-finite gradient {f}"
        if not vis[0]:
            assert not np.any(a[0]), f"{field}={poison}: culled Gaussian has gradient {f}"
    if not may_overflow and poison not in ("tile",):
        check_render(device, g, cam, name=f"{field}={poison}")
