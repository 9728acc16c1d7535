"""The fused OpenCL path (`OpenCLBackend.render` / `render_vjp`, and `reings.render` on a device)
against the float64 reference, end to end.

Forward: rgb / depth / alpha / final_T within RASTER_FWD_ATOL (depth scaled by the largest depth)
outside the discontinuity band (`render_band`): pixels where the reference moves when ALPHA_MIN moves
by ±ALPHA_BAND_REL, nearly saturated pixels (final_T < T_BAND: the T_MIN early stop may be decided
the other way in float32), and the tiles of Gaussians whose projection sits on a rounding edge
(test_project._edge_rows). Inside the band at most MAX_FLIP_FRACTION of the pixels may differ.
Gradients: per field MIN_COSINE / MAX_REL_L2 (test_project.assert_grads_match).
Also: forward reuse in render_vjp, one blocking read per render (none with the sync-free binning),
determinism, no allocation churn, and the sync-free binning (docs/perf_notes.md §8) giving the bits
of the sync one on every path: render, render_vjp, render_frames, forward_device / backward_device
in both frame slots.
"""
from __future__ import annotations

import numpy as np
import pytest

from asserts import assert_close_outside_band, assert_grad_close
from cases import binning, make_camera, random_scene, rotation_viewmat
from test_project import _edge_rows, assert_grads_match
from tolerances import MAX_FLIP_FRACTION, MAX_REL_L2, MIN_COSINE, RASTER_FWD_ATOL

import reings
from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, tile_grid
from reings.types import FIELDS, Gaussians

BG = (0.1, 0.2, 0.3)
ALPHA_BAND_REL = 1e-4  # the 1/255 cut: pairs this close (relative) to ALPHA_MIN may flip in float32
T_BAND = 2e-3  # pixels this close to saturation: one more/less Gaussian changes them by <= ~T


def cotangents(cam, seed=0):
    rng = np.random.default_rng(seed)
    H, W = cam.height, cam.width
    return (rng.normal(size=(H, W, 3)).astype(np.float32), rng.normal(size=(H, W)).astype(np.float32),
            rng.normal(size=(H, W)).astype(np.float32))


def render_band(g, cam, background=BG, near=0.01, opacity_override=None, drop=None) -> np.ndarray:
    """[H, W] bool: pixels near a discontinuity of the forward (see the module docstring)."""
    W, H = cam.width, cam.height
    proj = ref.project_fwd(g, cam, near, opacity_override, drop)
    bins = ref.bin(proj, W, H)
    lo = ref.rasterize_fwd(proj, bins, W, H, background, alpha_min=ALPHA_MIN * (1 - ALPHA_BAND_REL))
    hi = ref.rasterize_fwd(proj, bins, W, H, background, alpha_min=ALPHA_MIN * (1 + ALPHA_BAND_REL))
    band = (lo.last != hi.last) | (np.abs(lo.alpha - hi.alpha) > RASTER_FWD_ATOL / 10)
    band |= np.minimum(lo.final_T, hi.final_T) < T_BAND
    tiles_x, tiles_y = tile_grid(W, H)
    edge = np.flatnonzero(_edge_rows(proj, g, cam, near))
    for gid in edge:  # every tile the Gaussian could touch on either side of the edge
        r = np.asarray(proj.tile_rect[gid])
        if proj.radii[gid] > 0:
            x0, y0, x1, y1 = max(r[0] - 1, 0), max(r[1] - 1, 0), min(r[2] + 1, tiles_x), min(r[3] + 1, tiles_y)
        else:  # culled on the reference side: it may cover anything on the device side
            x0, y0, x1, y1 = 0, 0, tiles_x, tiles_y
        band[y0 * TILE_SIZE:y1 * TILE_SIZE, x0 * TILE_SIZE:x1 * TILE_SIZE] = True
    return band


def check_render(device, g, cam, background=BG, near=0.01, opacity_override=None, name="", drop=None):
    be = get_backend(device)
    out = be.render(g, cam, background=background, near=near, opacity_override=opacity_override,
                    want_importance=True, drop=drop)
    _, _, o64, stats = ref.render64(g, cam, background, near, opacity_override, want_importance=True, drop=drop)
    H, W = cam.height, cam.width
    shapes = dict(rgb=(H, W, 3), depth=(H, W), alpha=(H, W), final_T=(H, W), importance=(len(g),))
    for f, shp in shapes.items():
        a = getattr(out, f)
        assert a.dtype == np.float32 and a.shape == shp, f"{name}: {f} {a.dtype} {a.shape}"
        assert np.all(np.isfinite(a)), f"{name}: non-finite {f}"
    band = render_band(g, cam, background, near, opacity_override, drop)
    budget = MAX_FLIP_FRACTION if band.mean() < 0.5 else 1.0
    for f in ("rgb", "alpha", "final_T"):
        b = band[..., None] if f == "rgb" else band
        assert_close_outside_band(getattr(out, f), getattr(o64, f), b, RASTER_FWD_ATOL, 1.0, name=f"{name}: {f}")
    zs = max(1.0, float(np.max(ref.project_fwd(g, cam, near).depths, initial=1.0)))
    assert_close_outside_band(out.depth, o64.depth, band, RASTER_FWD_ATOL * zs, 1.0, name=f"{name}: depth")
    # pixels behind two alpha-clamped Gaussians sit on the T_MIN tie: (1 - ALPHA_MAX)^2 is T_MIN in
    # float64 (blended) and just below it in float32 (the stop comes first); common where
    # opacities exceed 1 (DropGaussian's compensation, tests/test_drop.py), inside the band anyway
    tie = (np.abs(o64.final_T - (1.0 - ALPHA_MAX) ** 2) <= 1e-12) if drop is not None else np.zeros((H, W), bool)
    assert np.count_nonzero((np.abs(out.alpha - o64.alpha) > RASTER_FWD_ATOL) & ~tie) <= max(2, budget * W * H), \
        f"{name}: too many pixels differ"
    if o64.importance.any():
        assert_grad_close(out.importance, o64.importance, name=f"{name}: importance", min_cosine=MIN_COSINE,
                          max_rel_l2=max(MAX_REL_L2, 10 * band.mean()))
    if not band.any():
        assert out.stats["visible"] == stats["visible"]
        assert out.stats["intersections"] == stats["intersections"]
    return out, o64, band


def check_vjp(device, g, cam, background=BG, near=0.01, opacity_override=None, grad_fields=None,
              which=("rgb", "depth", "alpha"), seed=0, name="", drop=None):
    vr, vd, va = cotangents(cam, seed)
    vr = vr if "rgb" in which else np.zeros_like(vr)
    vd = vd if "depth" in which else None
    va = va if "alpha" in which else None
    be = get_backend(device)
    dev = be.render_vjp(g, cam, vr, vd, va, background=background, near=near,
                        opacity_override=opacity_override, grad_fields=grad_fields, drop=drop)
    exp = ref.render_vjp64(g, cam, vr, vd, va, background, near, opacity_override, drop=drop)
    assert_grads_match(dev, exp, FIELDS if grad_fields is None else grad_fields, name)
    if opacity_override is not None:
        assert not dev.opacity_logits.any()
    return dev, exp


# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sh_degree", [0, 3])
def test_render_matches_reference(device, sh_degree):
    g, cam = random_scene(150, 64, 48, seed=sh_degree, sh_degree=sh_degree, scale_median=0.1,
                          viewmat=rotation_viewmat())
    check_render(device, g, cam, name=f"sh{sh_degree}")


def test_render_override_near_background(device):
    g, cam = random_scene(150, 70, 45, seed=7, sh_degree=1, scale_median=0.1)
    check_render(device, g, cam, background=(1.0, 0.0, 0.5), near=3.0, opacity_override=0.99, name="override")


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_render_vjp_matches_reference(device, sh_degree):
    g, cam = random_scene(150, 64, 48, seed=20 + sh_degree, sh_degree=sh_degree, scale_median=0.1,
                          viewmat=rotation_viewmat())
    check_vjp(device, g, cam, name=f"sh{sh_degree}")


@pytest.mark.parametrize("which", [("rgb",), ("depth",), ("alpha",)])
def test_render_vjp_partial_cotangents(device, which):
    g, cam = random_scene(120, 48, 40, seed=3, sh_degree=2, scale_median=0.1)
    check_vjp(device, g, cam, which=which, seed=1, name=str(which))


def test_render_vjp_override_and_grad_fields(device):
    """DNGaussian's two depth terms: hard (override 0.99, means only) and soft (opacities only)."""
    g, cam = random_scene(120, 48, 40, seed=4, sh_degree=0, scale_median=0.1)
    check_vjp(device, g, cam, opacity_override=0.99, grad_fields=("means",), which=("depth",), name="hard")
    check_vjp(device, g, cam, grad_fields=("opacity_logits",), which=("depth",), name="soft")


def test_public_api(device):
    g, cam = random_scene(60, 40, 30, seed=5, sh_degree=1, scale_median=0.1)
    out = reings.render(g, cam, device=device)
    assert out.rgb.shape == (30, 40, 3) and out.depth.shape == (30, 40) and out.alpha.shape == (30, 40)
    assert out.rgb.dtype == np.float32
    vr, vd, va = cotangents(cam)
    gr = reings.render_vjp(g, cam, vr, device=device)
    assert isinstance(gr, Gaussians) and gr.sh.shape == g.sh.shape
    exp = ref.render_vjp64(g, cam, vr, None, None)
    assert_grads_match(gr, exp, FIELDS, "public")


def test_vjp_reuses_forward_exactly(device):
    """render -> render_vjp reuses the forward on CPU devices; the result is bit-identical to a
    recomputed forward, and an in-place change of an input is detected (recomputed)."""
    be = get_backend(device)
    g, cam = random_scene(100, 48, 40, seed=6, sh_degree=1, scale_median=0.1)
    vr, vd, va = cotangents(cam, 3)
    be.render(g, cam, background=BG)
    reused = be.render_vjp(g, cam, vr, vd, va, background=BG)
    if be.cpu:
        assert "project_fwd" not in be.last_profile, "render_vjp did not reuse the forward"
    be.project_fwd(g, cam)  # any other call invalidates the forward state
    fresh = be.render_vjp(g, cam, vr, vd, va, background=BG)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(reused, f), getattr(fresh, f), err_msg=f)
    # mutate in place between render and render_vjp: must not reuse a stale forward
    be.render(g, cam, background=BG)
    g.means[0] += np.float32(0.05)
    g.sh[3, 0, 1] += np.float32(0.5)
    after = be.render_vjp(g, cam, vr, vd, va, background=BG)
    exp = ref.render_vjp64(g, cam, vr, vd, va, BG)
    assert_grads_match(after, exp, FIELDS, "mutated")
    be.project_fwd(g, cam)
    again = be.render_vjp(g, cam, vr, vd, va, background=BG)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(after, f), getattr(again, f), err_msg=f)
    # a different camera / background is not reused either
    be.render(g, cam, background=BG)
    other = be.render_vjp(g, cam, vr, vd, va, background=(0.0, 0.0, 0.0))
    exp = ref.render_vjp64(g, cam, vr, vd, va, (0.0, 0.0, 0.0))
    assert_grads_match(other, exp, FIELDS, "other background")


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_one_blocking_read(device, monkeypatch, mode):
    """At most one blocking device->host read per render (the (V, K) counts; none with the
    sync-free binning); outputs come back in one batch of non-blocking reads and a single wait."""
    import pyopencl as cl

    be = get_backend(device)
    g, cam = random_scene(100, 48, 40, seed=8, sh_degree=0, scale_median=0.1)
    vr, _, _ = cotangents(cam)
    want = {"sync": 1, "async": 0}[mode]
    with binning(be, mode) as done:
        be.render(g, cam)  # warm up (builds)
        calls = []
        real = cl.enqueue_copy

        def spy(queue, dest, src, **kw):
            if isinstance(dest, np.ndarray) and kw.get("is_blocking", True):
                calls.append(dest.nbytes)
            return real(queue, dest, src, **kw)

        monkeypatch.setattr(cl, "enqueue_copy", spy)
        out = be.render(g, cam)
        assert len(calls) == want, f"render: {len(calls)} blocking reads"
        calls.clear()
        be.render_vjp(g, cam, vr)
        assert len(calls) <= want, f"render_vjp: {len(calls)} blocking reads"
        monkeypatch.undo()
    assert done[mode] >= 2 and out.stats["intersections"] > out.stats["visible"] > 0


def _forward_backward_device(be, g, cam, vr, vd, va, **kw):
    """forward_device + backward_device on uploaded Gaussians: the images, the gradients and the
    counts, read back (the device trainer's path without its state)."""
    n, k = len(g), g.sh.shape[1]
    fr = be.forward_device(be._upload_gaussians(g), n, k, cam, BG, **kw)
    H, W = cam.height, cam.width
    imgs = [be._read(fr.bufs[b], shp, np.float32) for b, shp in (("out_rgb", (H, W, 3)), ("out_depth", (H, W)),
                                                                 ("out_alpha", (H, W)), ("out_T", (H, W)))]
    cot = [be._upload("pixel", f"test_{i}", a) for i, a in enumerate((vr, vd, va))]
    out = be.backward_device(fr, *cot, opacity_override=kw.get("opacity_override"))
    cols = {"means": 3, "quats": 4, "log_scales": 3, "opacity_logits": 1, "sh": 3 * k}
    grads = [be._read(out[f], (n, cols[f]), np.float32) for f in FIELDS]
    v_proj = be._read(fr.bufs["v_proj"], (n, 10), np.float32)
    radii = be._read(fr.bufs["radii"], (n,), np.int32)
    be._finish()
    v_proj[radii <= 0] = 0  # rows of culled gids are not written
    return imgs + grads + [v_proj], (fr.visible, fr.isects), be.last_stats


def test_sync_free_binning_is_bit_identical(device):
    """Every path that bins on the device, sync-free against sync: the same bits (images, importance,
    gradients, densification records) and the same counts. forward_device / backward_device with
    an opacity override, with DropGaussian, and into the kept frame slot."""
    from reings.backends.reference_drop import Drop

    be = get_backend(device)
    from dataclasses import replace

    g, cam = random_scene(700, 96, 72, seed=12, sh_degree=1, scale_median=0.15)
    cam = replace(cam, viewmat=rotation_viewmat(t=(0.05, -0.02, 0.1)))
    vr, vd, va = cotangents(cam, 4)
    res = {}
    for mode in ("sync", "async"):
        with binning(be, mode) as done:
            out = be.render(g, cam, background=BG, want_importance=True)
            grads = be.render_vjp(g, cam, vr, vd, va, background=BG)
            frames = [rgb for rgb, _ in be.render_frames(g, [cam, make_camera(40, 30)], background=BG)]
            dev = [_forward_backward_device(be, g, cam, vr, vd, va, **kw)
                   for kw in ({}, dict(opacity_override=0.95), dict(drop=Drop.at_rate(0.3, 77)), dict(keep=True))]
        forwards = 7 if be.cpu else 8  # render_vjp reuses render's forward on CPU devices
        assert done == {"sync": forwards if mode == "sync" else 0, "async": forwards if mode == "async" else 0}
        res[mode] = ([out.rgb, out.depth, out.alpha, out.final_T, out.importance] + [getattr(grads, f) for f in FIELDS]
                     + frames, out.stats, dev)
    (a, sa, da), (b, sb, db) = res["sync"], res["async"]
    assert sa == sb and sa["intersections"] > 2 * sa["visible"] > 0
    for i, (x, y) in enumerate(zip(a, b)):
        np.testing.assert_array_equal(x, y, err_msg=f"render output {i}")
    for (xs, xc, xl), (ys, yc, yl) in zip(da, db):
        assert xc == yc and xl == yl == dict(visible=xc[0], intersections=xc[1])
        for i, (x, y) in enumerate(zip(xs, ys)):
            np.testing.assert_array_equal(x, y, err_msg=f"device path output {i}")
    assert da[0][1] != da[1][1] != da[2][1]  # the override and the mask change the counts


def test_deterministic_and_no_allocation_churn(device):
    be = get_backend(device)
    g, cam = random_scene(200, 64, 48, seed=9, sh_degree=3, scale_median=0.1)
    vr, vd, va = cotangents(cam)
    a = be.render(g, cam, want_importance=True)
    ga = be.render_vjp(g, cam, vr, vd, va)
    n0 = be.scratch.allocations
    for _ in range(3):
        b = be.render(g, cam, want_importance=True)
        gb = be.render_vjp(g, cam, vr, vd, va)
    assert be.scratch.allocations == n0, "steady-state renders allocated device buffers"
    for f in ("rgb", "depth", "alpha", "final_T", "importance"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(ga, f), getattr(gb, f), err_msg=f)
    # a smaller scene reuses the same (larger) buffers
    g2, cam2 = random_scene(50, 32, 32, seed=1, sh_degree=0)
    be.render(g2, cam2)
    be.render_vjp(g2, cam2, cotangents(cam2)[0])
    assert be.scratch.allocations == n0


def test_render_empty_and_one(device):
    be = get_backend(device)
    cam = make_camera(24, 20)
    out = be.render(Gaussians.empty(2), cam, background=BG, want_importance=True)
    np.testing.assert_array_equal(out.rgb, np.broadcast_to(np.float32(BG), (20, 24, 3)))
    assert not out.alpha.any() and not out.depth.any() and np.all(out.final_T == 1)
    assert out.importance.shape == (0,) and out.stats == dict(visible=0, intersections=0)
    gr = be.render_vjp(Gaussians.empty(2), cam, cotangents(cam)[0])
    assert gr.sh.shape == (0, 9, 3)


def test_bench_smoke(device, tmp_path):
    """`reings bench` end to end at a tiny size: JSON lines with the documented keys."""
    import json

    from reings.bench import main

    out = tmp_path / "bench.jsonl"
    assert main(["--device", device, "--scenes", "A", "--sh", "0", "--n", "1500", "--warmup", "0",
                 "--repeats", "1", "--sort", "ours", "--sort-n", "4000", "--pairs", "estimate", "--crop", "32",
                 "--out", str(out)]) == 0
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    kinds = [r["kind"] for r in recs]
    assert kinds == ["render", "sort", "sort"]
    r = recs[0]
    for k in ("device", "driver", "visible", "intersections", "evaluated_pairs", "wall_step_ms",
              "dev_project_fwd_ms", "dev_rasterize_bwd_ms", "max_err_rgb", "grad_cos_means"):
        assert k in r, k
    assert r["max_err_rgb"] < 1e-3 and r["grad_cos_means"] > 0.999
    assert all(s["ours_correct"] for s in recs[1:])


def test_buffer_beyond_the_device_limit_is_named():
    """Issue 14 item 13: a render larger than the device's largest buffer raised a raw
    pyopencl LogicError (INVALID_BUFFER_SIZE); now a ValueError names the buffer, size and limit.
    The limit is lowered on a private backend instead of allocating gigabytes."""
    import reings
    from reings.backends.opencl.backend import OpenCLBackend
    from reings.backends.opencl.scratch import DeviceLimitError

    scene = reings.make_procedural_scene(n_views=1, width=64, height=48, supersample=1)
    rng = np.random.default_rng(0)
    from reings.train import gaussians_from_points, random_points_in_box

    g = gaussians_from_points(random_points_in_box([-1, 0, 0], [1, 1, 3], 50, rng), None, 0, rng)
    be = OpenCLBackend("pocl")
    be.render(g, scene.cameras[0])  # fits
    be.scratch.max_alloc = 64 * 48 * 4  # one float per pixel: the RGB buffers no longer fit
    big = scene.cameras[0]
    from dataclasses import replace

    big = replace(big, width=128, height=96, K=big.K * np.array([[2], [2], [1]]))
    with pytest.raises(DeviceLimitError, match=r"needs \d+ bytes .* largest allocation, 12288 bytes"):
        be.render(g, big)
    assert isinstance(DeviceLimitError("x"), ValueError)
