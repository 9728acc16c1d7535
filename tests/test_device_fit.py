"""The device-resident training engine (`fit(engine="device")`, reings/backends/opencl/trainer.py)
against the host engine (`engine="host"`: numpy Gaussians through render / render_vjp and numpy
Adam), and its checkpoint resume.

Case: the procedural scene at 64x48, 3 views, 300 random Gaussians at SH degree 1, the dngaussian
preset squeezed to 23 iterations: hard depth from iteration 1, soft depth from 3, the SH degree
raised at iteration 4, shape / scale / opacity penalties, clean_views, the depth smoothness from
iteration 12, and densification at iterations 10 and 20 (splits happen: the Gaussian count changes).

Tolerance: both engines run the same kernels for the passes; they differ only where the device
engine does on the device what the host engine does in numpy (Adam, penalties, statistics). Those
kernels follow numpy's operation order, in double where numpy is double, so on PoCL (correctly
rounded sqrt / division, cl_khr_fp64) the two engines are bit-identical, which the test asserts
there. Elsewhere (e.g. NVIDIA OpenCL, whose sqrt / division need not be correctly rounded) they
may differ by float32 rounding that the iterations carry along: |diff| <= 2e-5 + 1e-5 |x|, below a
sixth of the smallest single Adam step (sh_rest lr 1.25e-4), so a missing term, a wrong lr or step
count, or a wrong group still fails.

The sync-free binning (docs/perf_notes.md §8) against the sync one: the same fit bit for bit on
every device (the same kernels on the same data; only buffer capacities and launch sizes differ)."""
from __future__ import annotations

import os

import numpy as np
import pytest

from cases import binning, dngaussian_fit_case, interrupt_and_resume
from reings.backends import get_backend
from reings.backends.opencl import quirks
from reings.train import fit

ATOL, RTOL = 2e-5, 1e-5


@pytest.fixture(scope="module")
def case():
    return dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                               soft_depth_from=3, densify_until=25)


def _fit(case, device, **kw):
    scene, init, cfg = case
    return fit(scene, cfg, device=device, init=init, depth_targets=list(scene.depths), progress=False,
               log_every=5, **kw)


def _assert_same_state(a, b, exact: bool, what: str):
    assert len(a) == len(b), f"{what}: {len(a)} vs {len(b)} Gaussians"
    assert a.adam.step == b.adam.step, what
    assert a.iteration == b.iteration
    pairs = [(f"param/{k}", a.params[k], b.params[k]) for k in a.params]
    pairs += [(f"exp_avg/{k}", a.adam.exp_avg[k], b.adam.exp_avg[k]) for k in a.params]
    pairs += [(f"stat/{k}", a.stats[k], b.stats[k]) for k in a.stats]
    for name, x, y in pairs:
        assert x.shape == y.shape and x.dtype == y.dtype, f"{what} {name}"
        if exact:
            np.testing.assert_array_equal(x, y, err_msg=f"{what} {name}")
        else:
            np.testing.assert_allclose(x, y, rtol=RTOL, atol=ATOL, err_msg=f"{what} {name}")


@pytest.mark.parametrize("adam", ["kernel", "numpy"])
def test_device_fit_matches_host_fit(device, case, adam):
    host = _fit(case, device, engine="host")
    dev = _fit(case, device, engine="device", adam=adam)
    h, d = host.history, dev.history
    assert [n for _, n in h.densify] == [n for _, n in d.densify] and len(h.densify) == 2
    assert h.densify[0][1]["split"] > 0, "the case must exercise a split"
    assert h.iteration == d.iteration == [5, 10, 15, 20, 23]
    assert h.n_gaussians == d.n_gaussians
    np.testing.assert_allclose(d.loss, h.loss, rtol=1e-5)
    np.testing.assert_allclose(d.train_psnr, h.train_psnr, rtol=1e-5)
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _assert_same_state(host.state, dev.state, exact, f"device engine (adam={adam}) vs host engine")
    for f in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_allclose(getattr(dev.gaussians, f), getattr(host.gaussians, f), rtol=RTOL, atol=ATOL)
    # sh_rest starts at zero and is active from iteration 4: it moved by far more than the tolerance
    assert np.abs(dev.state.params["sh_rest"]).max() > 10 * ATOL


def test_device_fit_checkpoint_resume(device, case, tmp_path):
    """Interrupted at iteration 12 (last checkpoint at 10, before the second densification) and
    resumed: the same state as the uninterrupted run."""
    ref = _fit(case, device, engine="device")
    res = interrupt_and_resume(lambda **kw: _fit(case, device, engine="device", **kw),
                               os.path.join(tmp_path, "ck.npz"), stop_at=12)
    _assert_same_state(ref.state, res.state, True, "resumed vs uninterrupted")
    assert res.history.iteration == ref.history.iteration
    assert [tuple(x) for x in res.history.densify] == ref.history.densify  # JSON turns tuples into lists
    np.testing.assert_array_equal(res.history.loss, ref.history.loss)


def test_device_fit_sync_free_binning_is_bit_identical(device, case, tmp_path):
    """The device engine binning sync-free (no blocking read of (V, K)) against binning in sync:
    the same state, moments, statistics and history, bit for bit; and a resume from a checkpoint of
    a sync-free fit (interrupted at 12) lands on the same bits."""
    from reings.backends.opencl.harness import ClCalls

    be = get_backend(device)
    with binning(be, "sync") as sync:
        ref = _fit(case, device, engine="device")
    with binning(be, "async") as free, ClCalls() as calls_free:
        got = _fit(case, device, engine="device")
    assert sync["async"] == free["sync"] == 0 and free["async"] == sync["sync"] == 67, (sync, free)  # 23 + 21 soft + 23 hard
    _assert_same_state(ref.state, got.state, True, "sync-free vs sync binning")
    h, d = ref.history, got.history
    assert h.loss == d.loss and h.train_psnr == d.train_psnr and h.n_gaussians == d.n_gaussians
    assert [tuple(x) for x in h.densify] == [tuple(x) for x in d.densify]
    # every forward's blocking read is gone: the fit's own reads remain (logging, downloads)
    with binning(be, "sync"), ClCalls() as calls_sync:
        _fit(case, device, engine="device")
    assert calls_sync.n["reads_blocking"] - calls_free.n["reads_blocking"] == sync["sync"]
    with binning(be, "async"):
        res = interrupt_and_resume(lambda **kw: _fit(case, device, engine="device", **kw),
                                   os.path.join(tmp_path, "ck.npz"), stop_at=12)
    _assert_same_state(ref.state, res.state, True, "sync-free resumed vs sync uninterrupted")


def test_engine_choice(case):
    scene, init, cfg = case
    with pytest.raises(ValueError, match="OpenCL"):
        fit(scene, cfg, device="reference", init=init, engine="device", progress=False)
    with pytest.raises(ValueError, match="engine"):
        fit(scene, cfg, device="reference", init=init, engine="gpu", progress=False)


def _shared(case):
    from dataclasses import replace

    scene, init, cfg = case
    return scene, init, replace(cfg, loss=replace(cfg.loss, soft_depth_shared=True))


def test_shared_soft_depth_device_matches_host_and_changes_the_fit(device, case):
    """soft_depth_shared: the device engine against the host engine (bit-identical on PoCL), and
    a different result from the two-pass iteration (the switch does something)."""
    sc = _shared(case)
    host = _fit(sc, device, engine="host")
    dev = _fit(sc, device, engine="device")
    assert host.history.n_gaussians == dev.history.n_gaussians
    np.testing.assert_allclose(dev.history.loss, host.history.loss, rtol=1e-5)
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _assert_same_state(host.state, dev.state, exact, "shared soft depth: device vs host")
    two = _fit(case, device, engine="device")
    soft_its = 23 - 3 + 1  # the soft term from iteration 3 of 23
    steps = dict(dev.state.adam.step)
    assert steps["opacity_logits"] == 23 and two.state.adam.step == {**steps, "opacity_logits": 23 + soft_its}
    assert not np.array_equal(two.state.params["opacity_logits"][:50], dev.state.params["opacity_logits"][:50])


def test_fused_soft_backward_keeps_the_bits_and_saves_a_pass(device, case, monkeypatch):
    """The shared soft depth term's backward made in the photometric pass (backward(v_depth_opacity=),
    RASTER_BWD_DEPTH_O) against its own pass (DeviceTrainer.fuse_soft_backward = False): the same
    state bit for bit, and one rasterize_bwd fewer per iteration of the soft term."""
    from reings.backends.opencl.rasterize import Rasterizer
    from reings.backends.opencl.trainer import DeviceTrainer

    calls = {"all": 0, "fused": 0}
    orig = Rasterizer.bwd

    def counting(self, *a, **kw):
        calls["all"] += 1
        calls["fused"] += kw.get("v_depth_o") is not None
        return orig(self, *a, **kw)

    monkeypatch.setattr(Rasterizer, "bwd", counting)
    sc = _shared(case)
    got = {}
    for fuse in (False, True):
        monkeypatch.setattr(DeviceTrainer, "fuse_soft_backward", fuse)
        calls.update(all=0, fused=0)
        got[fuse] = (_fit(sc, device, engine="device"), dict(calls))
    soft_its = 23 - 3 + 1  # the soft term from iteration 3 of 23
    (sep, c_sep), (fus, c_fus) = got[False], got[True]
    assert c_sep["fused"] == 0 and c_fus["fused"] == soft_its, (c_sep, c_fus)
    assert c_sep["all"] - c_fus["all"] == soft_its, (c_sep, c_fus)
    _assert_same_state(sep.state, fus.state, True, "fused soft backward")
    assert sep.history.loss == fus.history.loss


def test_fused_soft_records_are_discarded_by_another_backward(device, case):
    """backward_device(v_depth_opacity=) holds the second records only for the very next backward:
    one in between (another cotangent, another frame) discards them, and the announced backward then
    runs its own pass, with the same result."""
    from reings.state import TrainState

    scene, init, _ = case
    be = get_backend(device)
    tr = be.trainer(list(scene.images), engine="device")
    tr.upload(TrainState.from_gaussians(init))
    tr.upload_depth_targets(list(scene.depths), [(c.height, c.width) for c in scene.cameras])
    cam = scene.cameras[0]
    fr = tr.forward(cam, 1, (0.0, 0.0, 0.0), 0.01)
    vd = tr.depth_loss(fr, 0, 3, 5, 0.01, 1.0, 1.0)
    v_rgb = tr.photometric(fr, 0, 0.8, 0.2)
    want = be._read(tr.backward(fr, None, vd, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
    be._finish()
    for between in (False, True):
        tr.backward(fr, v_rgb, None, v_depth_opacity=vd)
        assert be._pending_o is not None and be._pending_o[1] is vd
        if between:
            tr.backward(fr, v_rgb, None)  # discards the held records
            assert be._pending_o is None
        g = be._read(tr.backward(fr, None, vd, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
        be._finish()
        assert be._pending_o is None
        np.testing.assert_array_equal(g, want, err_msg=f"between={between}")
    # announced for one cotangent (A, the depth loss's buffer), called with another (a host array B): B's
    # own pass, though B is uploaded after the announcement (into a buffer of its own, never A's)
    vd_host = be._read(vd, (fr.height, fr.width), np.float32)
    be._finish()
    other = (vd_host[::-1] * 3.0).copy()
    want2 = be._read(tr.backward(fr, None, other, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
    be._finish()
    vd = tr.depth_loss(fr, 0, 3, 5, 0.01, 1.0, 1.0)  # A again (the same buffer as before)
    tr.backward(fr, v_rgb, None, v_depth_opacity=vd)
    g2 = be._read(tr.backward(fr, None, other, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
    be._finish()
    np.testing.assert_array_equal(g2, want2)
    assert not np.array_equal(want2, want)
    # the announced buffer rewritten before the announced backward (another depth loss): its own pass
    tr.backward(fr, v_rgb, None, v_depth_opacity=vd)
    vd2 = tr.depth_loss(fr, 0, 5, 9, 0.01, 1.0, 1.0)
    assert vd2 is vd and be._pending_o is None
    g3 = be._read(tr.backward(fr, None, vd2, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
    be._finish()
    tr.fuse_soft_backward = False
    want3 = be._read(tr.backward(fr, None, vd2, None, ("opacity_logits",))["opacity_logits"], (tr.n,), np.float32)
    be._finish()
    np.testing.assert_array_equal(g3, want3)


@pytest.mark.parametrize("engine", ["host", "device"])
def test_shared_soft_depth_steps_the_sum_of_both_gradients(device, case, engine):
    """One iteration with only the soft depth term and the photometric loss, shared: Adam's first
    moment after its first step is (1 - beta1) g, so g of the opacities must be the photometric
    gradient plus the soft depth gradient, both at the initial parameters, and g of the means the
    photometric gradient alone. Expected values from the backend's render / render_vjp and its
    losses, called here directly (patch sizes drawn as the fit draws them)."""
    from dataclasses import replace

    from reings.losses import draw_depth_patches, photometric_weights
    from reings.train import _view_of

    scene, init, cfg = case
    L = replace(cfg.loss, hard_depth=False, soft_depth=True, soft_depth_from=1, soft_depth_shared=True,
                depth_smooth_weight=0.0, shape_pena=0.0, scale_pena=0.0, opa_pena=0.0)
    cfg1 = replace(cfg, iterations=1, sh_degree=0, loss=L, densify=replace(cfg.densify, clean_views=False))
    init0 = type(init)(init.means, init.quats, init.log_scales, init.opacity_logits, init.sh[:, :1])
    r = fit(scene, cfg1, device=device, init=init0, depth_targets=list(scene.depths), progress=False,
            engine=engine)
    b = get_backend(device)
    vi = _view_of(1, cfg1.seed, len(scene))
    cam, gt, target = scene.cameras[vi], scene.images[vi], scene.depths[vi]
    out = b.render(init0, cam, background=tuple(cfg1.background), near=cfg1.near)
    w_l1, w_ssim = photometric_weights(L.lambda_dssim, L.photometric_form)
    _, v_rgb = b.photometric_loss(out.rgb, gt, w_l1, w_ssim)
    g_photo = b.render_vjp(init0, cam, v_rgb, background=tuple(cfg1.background), near=cfg1.near)
    pl, pg = draw_depth_patches(np.random.default_rng(cfg1.seed), L.depth_patch_range, cam.height, cam.width)
    _, v_depth = b.depth_loss(out.depth, target, pl, pg, L.depth_margin, L.depth_w_local, L.depth_w_global)
    g_soft = b.render_vjp(init0, cam, np.zeros_like(v_rgb), v_depth, background=tuple(cfg1.background),
                          near=cfg1.near, grad_fields=("opacity_logits",))
    assert np.abs(g_soft.opacity_logits).max() > 0 and np.abs(g_photo.opacity_logits).max() > 0
    m = r.state.adam.exp_avg
    k = 1 - cfg1.optim.beta1
    want = (g_photo.opacity_logits + g_soft.opacity_logits).astype(np.float32)
    np.testing.assert_allclose(m["opacity_logits"] / k, want, rtol=2e-4, atol=1e-9 + 1e-4 * np.abs(want).max())
    np.testing.assert_allclose(m["means"] / k, g_photo.means, rtol=2e-4, atol=1e-4 * np.abs(g_photo.means).max())
    # the soft term's share is not negligible: without it the opacities' moment would be off
    assert np.abs(g_soft.opacity_logits).max() > 1e-2 * np.abs(g_photo.opacity_logits).max()
    # the densification statistics come from the photometric backward alone: the same as a fit
    # without the soft term (same parameters at the photometric pass)
    r0 = fit(scene, replace(cfg1, loss=replace(L, soft_depth=False)), device=device, init=init0,
             depth_targets=list(scene.depths), progress=False, engine=engine)
    assert any(np.abs(v).max() > 0 for v in r.state.stats.values())
    for k in r.state.stats:
        np.testing.assert_array_equal(r.state.stats[k], r0.state.stats[k], err_msg=k)


def test_photometric_value_switch(device, case):
    """Trainer.photometric(value=False) (the training steps whose loss nobody reads skip the loss's
    reduction, docs/perf_notes.md §11): the same dL/d rgb bytes as value=True and one launch fewer;
    read_loss refuses after it (also after an earlier value=True pass: no stale loss), and after a
    value=True pass returns the float64 reference's loss of the read image."""
    from reings.backends import reference_loss as R
    from reings.backends.opencl.harness import ClCalls
    from reings.state import TrainState

    scene, init, _ = case
    tr = get_backend(device).trainer(scene.images, engine="device")
    tr.upload(TrainState.from_gaussians(init, 1))
    fr = tr.forward(scene.cameras[0], 1, (0, 0, 0), 0.01)
    rgb = tr.read_rgb(fr)
    n = fr.width * fr.height * 3
    want, _ = R.weighted_photometric_fwd_bwd(rgb.astype(np.float64), np.asarray(scene.images[0], np.float64), 0.8, 0.2)
    grads, launches = [], []
    for value in (True, False, True, False):
        with ClCalls() as calls:
            v = tr.photometric(fr, 0, 0.8, 0.2, value=value)
        launches.append(calls.n["launches"])
        grads.append(tr._read(v, (n,), np.float32))
        if value:
            assert abs(tr.read_loss() - float(want)) <= 1e-5 * abs(float(want)) + 1e-7
        else:
            with pytest.raises(RuntimeError, match="computed no loss"):
                tr.read_loss()
    for g in grads[1:]:
        np.testing.assert_array_equal(g, grads[0])
    assert launches[0] == launches[2] == launches[1] + 1 == launches[3] + 1


def test_fit_reduces_the_loss_only_on_logging_iterations(device, case):
    """The fit passes value=log: loss_row_sums runs once per logging iteration and on no other."""
    import pyopencl._cl as _cl

    names = []
    orig = _cl.enqueue_nd_range_kernel

    def launch(queue, kernel, *a, **k):
        names.append(kernel.function_name)
        return orig(queue, kernel, *a, **k)

    _cl.enqueue_nd_range_kernel = launch
    try:
        res = _fit(case, device, engine="device")
    finally:
        _cl.enqueue_nd_range_kernel = orig
    assert res.history.iteration == [5, 10, 15, 20, 23]
    assert names.count("loss_row_sums") == len(res.history.iteration)
    assert names.count("ssim_vpass_bwd") + names.count("ssim_bwd_tile") == 23  # every step's gradient (GPUs: fused)


def test_opacity_only_backward_is_wired(device, case):
    """backward(grad_fields=("opacity_logits",)) (the soft depth and background passes) runs the
    rasterizer's opacity-only build: the frame's reduced records carry d/d opacity alone, with the bytes
    of the full backward's; any other field set runs the full build."""
    from reings.state import TrainState

    scene, init, _ = case
    tr = get_backend(device).trainer(scene.images, engine="device")
    tr.upload(TrainState.from_gaussians(init, 1))
    rng = np.random.default_rng(5)
    cam = scene.cameras[0]
    vd = rng.normal(size=(cam.height, cam.width)).astype(np.float32)
    recs = {}
    for fields in (None, ("opacity_logits",), ("opacity_logits", "means")):
        fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
        tr.backward(fr, None, vd, None, fields)
        recs[fields] = tr._read(fr.bufs["v_proj"], (tr.n, 10), np.float32)[tr._read(fr.bufs["radii"], (tr.n,), np.int32) > 0]
    full, only, two = recs[None], recs[("opacity_logits",)], recs[("opacity_logits", "means")]
    assert np.abs(full[:, :2]).max() > 0 and np.abs(full[:, 8]).max() > 0
    np.testing.assert_array_equal(only[:, 8].view(np.uint32), full[:, 8].view(np.uint32))
    assert not np.delete(only, 8, axis=1).any()
    np.testing.assert_array_equal(two.view(np.uint32), full.view(np.uint32))


def test_opacity_only_backward_runs_project_bwd_opacity(device, case):
    """An opacity-only backward (the soft depth and background passes) launches project_bwd_opacity, not
    project_bwd, and leaves project_bwd's bytes in every field: plain, and added into the held gradients of a
    photometric backward that announced it (the shared soft depth term: its records reduced, `backward(into=)`).
    tests/test_project.py pins the kernel's cases (masks, override, poison cotangents, accumulate start values)."""
    import pyopencl._cl as _cl

    from reings.backends.base import grad_columns
    from reings.state import TrainState

    scene, init, _ = case
    tr = get_backend(device).trainer(scene.images, engine="device")
    tr.upload(TrainState.from_gaussians(init, 1))
    cam = scene.cameras[0]
    vd = tr.mem.get("pixel", "test_v_depth", cam.width * cam.height, 4)
    tr._write(vd, np.random.default_rng(5).normal(size=(cam.height, cam.width)).astype(np.float32))
    orig, old = _cl.enqueue_nd_range_kernel, tr.b.proj_bwd_opacity
    res = {}
    try:
        for cheap in (False, True):
            tr.b.proj_bwd_opacity = cheap
            names = []

            def launch(queue, kernel, *a, **k):
                names.append(kernel.function_name)
                return orig(queue, kernel, *a, **k)

            _cl.enqueue_nd_range_kernel = launch
            fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
            gr = tr.backward(fr, tr.photometric(fr, 0, 0.8, 0.2), None, v_depth_opacity=vd, hold=True)
            tr.backward(fr, None, vd, None, ("opacity_logits",), into=gr)
            out = [tr._read(gr[f], (tr.n * c,), np.uint32) for f, c in grad_columns(fr.sh_k).items()]
            fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
            g = tr.backward(fr, None, vd, None, ("opacity_logits",))
            out += [tr._read(g[f], (tr.n * c,), np.uint32) for f, c in grad_columns(fr.sh_k).items()]
            _cl.enqueue_nd_range_kernel = orig
            res[cheap] = out
            assert names.count("project_bwd_opacity") == (2 if cheap else 0), names
            assert names.count("project_bwd") == (1 if cheap else 3), names
    finally:
        _cl.enqueue_nd_range_kernel, tr.b.proj_bwd_opacity = orig, old
    for i, (a, b) in enumerate(zip(res[False], res[True])):
        assert np.array_equal(a, b), i
    o = res[True][3].view(np.float32)
    assert np.abs(o).max() > 0 and not res[True][5].any()  # the opacity's gradient; zeros in the plain one's others


@pytest.mark.parametrize("vw,fuse", [(1, True), (8, True), (16, True), (8, False)])
def test_backward_stats_adds_what_accumulate_adds(device, case, vw, fuse):
    """backward(stats=True) (project_bwd adds the densification statistics, densify.h) leaves the same
    statistics, bit for bit, as backward() then accumulate(fr) (densify_accumulate.cl), and the same
    gradients: a plain, a held and an into backward, three views, at SH 4, with one Gaussian per
    work-item (the GPU layout; PROJ_SH_STAGE where the backend stages SH rows, as on GPUs) and with
    eight or sixteen (the CPU layouts, backend.proj_lanes). fuse False: a trainer without doubles takes the separate launch after the
    backward (its float statistics are densify_accumulate.cl's, built correctly rounded). A backward
    of some fields only refuses stats."""
    from reings import densify as D
    from reings.state import TrainState

    scene, init, _ = case
    be = get_backend(device)
    old_vw, be.proj_vw = be.proj_vw, vw
    try:
        states, grads = [], []
        for fused in (False, True):
            st = TrainState.from_gaussians(init)
            st.params["sh_rest"] = np.random.default_rng(5).normal(0, 0.1, (len(st), 3, 3)).astype(np.float32)
            tr = be.trainer(list(scene.images), engine="device")
            tr.fuse_stats = tr.fuse_stats and fuse
            tr.upload(st)
            got = []
            for view, kw in ((0, {}), (1, {"hold": True}), (2, None)):
                fr = tr.forward(scene.cameras[view], 4, (0.0, 0.0, 0.0), 0.01)
                v_rgb = tr.photometric(fr, view, 0.8, 0.2)
                if kw is None:  # into the held gradients of the previous backward
                    g = tr.backward(fr, v_rgb, None, into=held, stats=fused)
                else:
                    g = tr.backward(fr, v_rgb, None, stats=fused, **kw)
                    held = g
                if not fused:
                    tr.accumulate(fr)
                got.append(be._read(g["means"], (tr.n, 3), np.float32))
                be._finish()
            for fields in (("opacity_logits",), ("means", "quats")):
                with pytest.raises(ValueError, match="every field"):
                    tr.backward(fr, v_rgb, None, None, fields, stats=True)
            with pytest.raises(ValueError, match="opacity-only"):  # the backend's own check
                be.backward_device(fr, v_rgb, None, None, None, ("opacity_logits",), stats=(None, None, None))
            out = TrainState.from_gaussians(init)
            tr.download(out)
            states.append(out.stats)
            grads.append(got)
        for k in (D.ACCUM, D.COUNT, D.RADII):
            np.testing.assert_array_equal(states[1][k], states[0][k], err_msg=k)
        assert states[0][D.COUNT].max() == 3 and states[0][D.ACCUM].max() > 0
        for a, b in zip(*grads):
            np.testing.assert_array_equal(a, b)
    finally:
        be.proj_vw = old_vw
