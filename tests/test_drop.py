"""DropGaussian (Park, Ryu, Kim, CVPR 2025, arXiv 2504.00773; docs/method.md §9): the counter-based
mask, its kernels against the float64 twin, the twin against finite differences, and the option
inside the training loop and the pipeline.

Checked:
  - the mask hash: the numpy twin (reference_drop.drop_hash) against a pure-Python fmix32, and
    the C macro (DROP_HASH of kernels/project.cl, scalar and uint8 lanes) against the numpy twin,
    bit for bit;
  - the kept fraction at rate r over 200k Gaussians is 1 - r within 4 standard errors; a
    threshold of 0 keeps every Gaussian and gives the same bits as no mask at all (projection,
    render, render_vjp);
  - project_fwd / project_bwd, render and render_vjp with a mask on this device against the twin
    (the existing tolerances of tests/test_project.py and tests/test_render.py), the visibility
    being exactly the unmasked visibility and the mask;
  - central finite differences of the twin's render VJP with the mask fixed, and the
    opacity-logit gradient's 1 / (1 - r) factor;
  - in a fit (the engine tests' case of tests/test_view_warp_fit.py, with the view_warp term):
    the device engine against the host engine (bit for bit on PoCL), a resumed fit against the
    uninterrupted one, the mask only in the photometric pass's renders (the same mask for the
    training view and the virtual view), an explicit no-op mask through the kernels giving the
    bits of a fit without the option;
  - the options: LossConfig / RunConfig checks, the recipe of each method, the resume settings,
    metrics.json.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest

from cases import (assert_resumes_bit_identically, assert_same_state, dngaussian_fit_case, fit_case, random_scene,
                   rotation_viewmat)
from test_project import check_project_bwd, check_project_fwd
from test_reference_fd import BG as FD_BG
from test_reference_fd import check_params_fd, fd_camera, fd_scene, render_loss, render_signature
from test_reference_fd import cotangents as fd_cotangents
from test_project import assert_grads_match
from test_render import BG, check_render, cotangents

from reings.backends import get_backend
from reings.backends import reference as ref
from reings.backends.base import ALPHA_MAX
from reings.backends.opencl import quirks
from reings.backends.reference_drop import (DROP_FMIX_MUL1, DROP_FMIX_MUL2, DROP_KEY_MUL, Drop, drop_hash,
                                            drop_threshold)
from reings.config import LossConfig, RunConfig
from reings.train import drop_at, fit
from reings.types import FIELDS

ATOL, RTOL = 2e-5, 1e-5  # the engines off PoCL (tests/test_device_fit.py)


# {{{ the hash

def _fmix32_py(gid: int, key: int) -> int:
    """murmur3's fmix32 of gid ^ (key * DROP_KEY_MUL), in Python integers: the specification."""
    m = 0xFFFFFFFF
    h = (gid ^ (key * DROP_KEY_MUL)) & m
    h ^= h >> 16
    h = (h * DROP_FMIX_MUL1) & m
    h ^= h >> 13
    h = (h * DROP_FMIX_MUL2) & m
    h ^= h >> 16
    return h


def test_numpy_hash_is_fmix32():
    rng = np.random.default_rng(0)
    gids = np.concatenate([np.arange(64), rng.integers(0, 2**32, 200), [2**32 - 1, 2**31]]).astype(np.int64)
    for key in (0, 1, 12345, 2**31, 2**32 - 1, *rng.integers(0, 2**32, 6).tolist()):
        got = drop_hash(gids, key)
        assert got.dtype == np.uint32
        assert got.tolist() == [_fmix32_py(int(g), int(key)) for g in gids], key
    assert drop_hash(np.array([0]), 0)[0] == 0  # fmix32(0) = 0


_HASH_KERNELS = """
#include "project.cl"
__kernel void hash1(__global const uint *gid, const uint key, __global uint *out) {
    const int i = get_global_id(0);
    uint h;
    DROP_HASH(h, gid[i], key);
    out[i] = h;
}
__kernel void hash8(__global const uint *gid, const uint key, __global uint *out) {
    const int i = get_global_id(0);
    uint8 h;
    DROP_HASH(h, vload8(i, gid), key);
    vstore8(h, i, out);
}
"""


def test_kernel_hash_matches_numpy_bit_for_bit(device):
    """DROP_HASH (kernels/project.cl) on uint and on uint8 lanes (project.cl's PROJ_VW 1 and 8)
    equals drop_hash over 4096 gids (random, small and extreme) x 40 keys."""
    import pyopencl as cl

    be = get_backend(device)
    ctx, q = be.handle.context, be.queue
    prg = cl.Program(ctx, _HASH_KERNELS).build(options=be.lib.options({}), devices=[be.handle.device])
    rng = np.random.default_rng(1)
    gids = np.concatenate([np.arange(2048), rng.integers(0, 2**32, 2040), 2**32 - 1 - np.arange(8)]).astype(np.uint32)
    assert gids.size == 4096
    mf = cl.mem_flags
    gbuf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=gids)
    obuf = cl.Buffer(ctx, mf.WRITE_ONLY, gids.nbytes)
    out = np.empty_like(gids)
    keys = [0, 1, 2**32 - 1, 0x9E3779B9, *rng.integers(0, 2**32, 36).tolist()]
    kernels = {name: cl.Kernel(prg, name) for name in ("hash1", "hash8")}
    for key in keys:
        want = drop_hash(gids.astype(np.int64), key)
        for name, n in (("hash1", gids.size), ("hash8", gids.size // 8)):
            kernels[name](q, (n,), None, gbuf, np.uint32(key), obuf)
            cl.enqueue_copy(q, out, obuf)
            np.testing.assert_array_equal(out, want, err_msg=f"{name} key {key}")


@pytest.mark.parametrize("rate", [0.05, 0.3, 0.5, 0.9])
def test_kept_fraction_is_one_minus_the_rate(rate):
    n = 200_000
    se = np.sqrt(rate * (1 - rate) / n)
    for key in (0, 7, 2**32 - 5):
        d = Drop.at_rate(rate, key)
        assert d.threshold == int(np.floor(rate * 2**32)) and d.scale == float(np.float32(1 / (1 - rate)))
        kept = d.kept(n)
        assert abs(kept.mean() - (1 - rate)) < 4 * se, (rate, key, kept.mean())
    # different keys give independent masks: 2 r (1 - r) of the Gaussians are kept by one only
    a, b = Drop.at_rate(rate, 1).kept(n), Drop.at_rate(rate, 2).kept(n)
    assert abs(np.mean(a != b) - 2 * rate * (1 - rate)) < 8 * se


def test_threshold_bounds_and_refusals():
    assert drop_threshold(0.0) == 0 and drop_threshold(1.0) == 2**32 - 1 and drop_threshold(0.5) == 2**31
    assert Drop.at_rate(0.0, 5) == Drop(5, 0, 1.0) and Drop(5, 0, 1.0).kept(10).all()
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="rate"):
            Drop.at_rate(bad, 0)
    with pytest.raises(ValueError, match="key"):
        Drop.at_rate(0.1, 2**32)


def test_drop_at_is_a_pure_function_of_seed_and_iteration():
    assert drop_at(0.0, 0, 5, 10) is None
    d = [drop_at(0.4, 3, it, 10) for it in range(1, 11)]
    assert d == [drop_at(0.4, 3, it, 10) for it in range(1, 11)]  # no state
    assert len({x.key for x in d}) == 10 and d[0].key != drop_at(0.4, 4, 1, 10).key
    assert [x.threshold for x in d] == [drop_threshold(0.4 * it / 10) for it in range(1, 11)]
    assert d[-1] == Drop.at_rate(0.4, d[-1].key)  # the largest rate, gamma, at the last iteration
    state = np.random.get_state()[1].copy()
    drop_at(0.4, 3, 1, 10)
    assert np.array_equal(np.random.get_state()[1], state)  # numpy's global generator untouched
# }}}


# {{{ kernels against the float64 twin

def _scene(n=400, seed=2):
    return random_scene(n, 80, 60, seed=seed, sh_degree=1, scale_median=0.08, viewmat=rotation_viewmat())


@pytest.mark.parametrize("vw", [1, 8, 16])
def test_project_with_drop_matches_twin(device, vw):
    """The visibility is the unmasked one and the mask, bit for bit; the kept Gaussians'
    projection, opacities (times drop.scale, above 1 for some) and gradients are the twin's."""
    be = get_backend(device)
    old = be.proj_vw
    be.proj_vw = vw
    try:
        g, cam = _scene()
        drop = Drop.at_rate(0.6, 99)
        dev, exp, both = check_project_fwd(device, g, cam, name=f"drop vw{vw}", drop=drop)
        plain = be.project_fwd(g, cam)
        kept = drop.kept(len(g))
        np.testing.assert_array_equal(dev.radii > 0, (plain.radii > 0) & kept)
        assert 0 < (dev.radii > 0).sum() < (plain.radii > 0).sum()
        vis = dev.radii > 0
        np.testing.assert_array_equal(dev.opacities[vis], (plain.opacities[vis] * np.float32(drop.scale)))
        assert (dev.opacities > 1).any(), "the scene must exercise opacities above 1"
        check_project_bwd(device, g, cam, name=f"drop vw{vw}", drop=drop)
    finally:
        be.proj_vw = old


def test_render_and_vjp_with_drop_match_twin(device):
    """project_fwd + bin + rasterize with a mask (some opacities above 1: the rasterizer's 0.99
    alpha clamp decides) against render64 (check_render's tolerances and band), and render_vjp
    against render_vjp64 (assert_grads_match); the dropped Gaussians get no gradient and no
    densification statistics (`last_screen`)."""
    g, cam = random_scene(150, 64, 48, seed=4, sh_degree=1, scale_median=0.1, viewmat=rotation_viewmat())
    drop = Drop.at_rate(0.5, 4242)
    proj = ref.project_fwd(g, cam, 0.01, None, drop)
    assert (proj.opacities > 1).any()
    out, o64, _ = check_render(device, g, cam, name="drop", drop=drop)
    assert out.alpha.max() <= 1.0
    # pixels on the T_MIN tie behind two alpha-clamped Gaussians stop one Gaussian apart in float32
    # and float64 (tests/test_render.py check_render): no cotangent there
    tie = np.abs(o64.final_T - (1.0 - ALPHA_MAX) ** 2) <= 1e-12
    vr, vd, va = cotangents(cam, 0)
    vr[tie], vd[tie], va[tie] = 0.0, 0.0, 0.0
    be = get_backend(device)
    dev = be.render_vjp(g, cam, vr, vd, va, background=BG, drop=drop)
    assert_grads_match(dev, ref.render_vjp64(g, cam, vr, vd, va, BG, drop=drop), FIELDS, "drop")
    dropped = ~drop.kept(len(g))
    for f in FIELDS:
        assert not getattr(dev, f)[dropped].any(), f"a dropped Gaussian has a {f} gradient"
    v2d, radii = be.last_screen
    assert not radii[dropped].any() and not v2d[dropped].any()
    # the mask changes the image (the option does something)
    plain = be.render(g, cam)
    assert np.abs(plain.rgb - out.rgb).max() > 1e-2


def test_threshold_zero_is_bit_identical_to_no_mask(device):
    g, cam = _scene(300, seed=5)
    noop = Drop(key=123456, threshold=0, scale=1.0)
    for be in (get_backend(device), ref.ReferenceBackend()):
        a, b = be.project_fwd(g, cam), be.project_fwd(g, cam, drop=noop)
        for f in ("means2d", "conics", "depths", "radii", "tile_rect", "colors", "opacities"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    be = get_backend(device)
    a, b = be.render(g, cam), be.render(g, cam, drop=noop)
    for f in ("rgb", "depth", "alpha", "final_T"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    rng = np.random.default_rng(0)
    vr = rng.normal(size=(cam.height, cam.width, 3)).astype(np.float32)
    a, b = be.render_vjp(g, cam, vr), be.render_vjp(g, cam, vr, drop=noop)
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_override_and_drop_are_refused_together(device):
    g, cam = _scene(20)
    for be in (get_backend(device), ref.ReferenceBackend()):
        with pytest.raises(ValueError, match="override"):
            be.render(g, cam, opacity_override=0.9, drop=Drop.at_rate(0.2, 1))
# }}}


# {{{ the twin against finite differences

def _key_dropping(n: int, rate: float, want: list) -> int:
    for key in range(10_000):
        if Drop.at_rate(rate, key).kept(n).tolist() == want:
            return key
    raise AssertionError("no key drops exactly the wanted Gaussians")


def test_twin_vjp_with_drop_matches_central_differences():
    """render_vjp64 with a mask that drops one of the four big Gaussians, the mask fixed, against
    central differences of render64 (every raw field; the scene checked away from
    discontinuities at every evaluation, tests/test_reference_fd.py)."""
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=1, seed=3, colour_clamp=False)
    rate = 0.25
    drop = Drop.at_rate(rate, _key_dropping(len(p), rate, [True, False, True, True]))
    vr, vd, va = fd_cotangents(3)
    ad = ref.render_vjp64(p, cam, vr, vd, va, FD_BG, alpha_min=0.0, drop=drop)
    for f in FIELDS:
        assert not np.any(getattr(ad, f)[1]), f"the dropped Gaussian has a {f} gradient"
    assert np.all(ref.project_fwd(p, cam, 0.01, None, drop).radii[[0, 2, 3]] > 0)
    check_params_fd(ad, p, render_loss(cam, vr, vd, va, FD_BG, drop=drop),
                    render_signature(cam, FD_BG, drop=drop), label="drop ")


def test_twin_opacity_gradient_carries_the_compensation():
    """Through the projection alone, dL/d logit of a kept Gaussian is 1 / (1 - r) (float32 of it)
    times the unmasked one, and the projected opacity is sigmoid(logit) / (1 - r)."""
    cam = fd_camera()
    p = fd_scene(cam, sh_degree=1, seed=3, colour_clamp=False)
    rate = 0.25
    drop = Drop.at_rate(rate, _key_dropping(len(p), rate, [True, False, True, True]))
    n = len(p)
    rng = np.random.default_rng(4)
    z = lambda k: np.zeros((n, k)) if k else np.zeros(n)  # noqa: E731
    gr = ref.RasterGrads(v_means2d=z(2), v_conics=z(3), v_colors=z(3), v_opacities=rng.normal(size=n),
                         v_depths=z(0))
    a = ref.project_bwd(p, cam, None, gr, 0.01, None, drop)
    b = ref.project_bwd(p, cam, None, gr, 0.01, None)
    keep = np.array([0, 2, 3])
    assert drop.scale == float(np.float32(1 / (1 - rate)))
    np.testing.assert_allclose(a.opacity_logits[keep], drop.scale * b.opacity_logits[keep], rtol=1e-14)
    assert a.opacity_logits[1] == 0 and b.opacity_logits[1] != 0
    pa, pb = ref.project_fwd(p, cam, 0.01, None, drop), ref.project_fwd(p, cam)
    np.testing.assert_allclose(pa.opacities[keep], drop.scale * pb.opacities[keep], rtol=1e-15)
# }}}


# {{{ in a fit

GAMMA = 0.5


@pytest.fixture(scope="module")
def case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    cfg = replace(cfg, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=12, view_warp_baseline=0.3,
                                    drop_gamma=GAMMA))
    return scene, init, cfg


def _fit(case, device, **kw):
    return fit_case(case, device, **kw)


def _same_state(a, b, exact: bool, what: str):
    assert_same_state(a, b, exact, what, RTOL, ATOL)


@pytest.mark.parametrize("shared", [False, True], ids=["two-pass", "shared-soft-depth"])
def test_fit_with_drop_device_matches_host(device, case, shared):
    scene, init, cfg = case
    sc = (scene, init, replace(cfg, loss=replace(cfg.loss, soft_depth_shared=shared)))
    host = _fit(sc, device, engine="host")
    dev = _fit(sc, device, engine="device")
    assert host.history.n_gaussians == dev.history.n_gaussians and len(host.history.densify) == 2
    np.testing.assert_allclose(dev.history.loss, host.history.loss, rtol=1e-5)
    exact = quirks.is_pocl(get_backend(device).handle.device)
    _same_state(host.state, dev.state, exact, f"drop ({'shared' if shared else 'two-pass'}): device vs host")


def test_fit_with_drop_resumes_bit_identically(device, case, tmp_path):
    """Stopped at 17, last checkpoint at 15 (inside the view_warp span)."""
    assert_resumes_bit_identically(case, device, tmp_path, stop_at=17)


def test_gamma_zero_and_a_noop_mask_give_the_fit_without_the_option(device, case, monkeypatch):
    """drop_gamma 0 hands the trainer no mask; a mask of threshold 0 at every iteration (the
    kernels' drop path, taken) gives the same bits; gamma > 0 changes the fit."""
    import reings.train as T

    scene, init, cfg = case
    off = (scene, init, replace(cfg, loss=replace(cfg.loss, drop_gamma=0.0)))
    plain = _fit(off, device, engine="device")
    monkeypatch.setattr(T, "drop_at", lambda gamma, seed, it, its, draws=None: Drop(key=it * 7919, threshold=0, scale=1.0))
    noop = _fit(off, device, engine="device")
    monkeypatch.undo()
    _same_state(plain.state, noop.state, True, "no-op mask vs no mask")
    on = _fit(case, device, engine="device")
    p, q = on.state.params["means"], plain.state.params["means"]
    assert p.shape != q.shape or np.abs(p - q).max() > 1e-4


def test_only_the_photometric_pass_drops(device, case, monkeypatch):
    """Every forward of the photometric pass (the training view, and the virtual view, rendered
    once as a kept frame) gets the iteration's mask, drop_at(gamma, seed, it, T); the hard and
    soft depth passes none."""
    from reings.backends.opencl.trainer import DeviceTrainer

    calls, stack = [], []
    orig_phase, orig_forward = DeviceTrainer.phase, DeviceTrainer.forward

    @contextmanager
    def phase(self, name):
        stack.append(name)
        try:
            with orig_phase(self, name):
                yield
        finally:
            stack.pop()

    def forward(self, cam, k, background, near, opacity_override=None, drop=None, keep=False):
        calls.append((stack[-1] if stack else None, opacity_override, drop))
        assert keep == (stack[-1:] == ["warp_render"])  # only the virtual view is a kept frame
        return orig_forward(self, cam, k, background, near, opacity_override, drop, keep)

    monkeypatch.setattr(DeviceTrainer, "phase", phase)
    monkeypatch.setattr(DeviceTrainer, "forward", forward)
    scene, init, cfg = case
    _fit(case, device, engine="device")
    photo = [d for ph, _, d in calls if ph == "photo_render"]
    assert len(photo) == cfg.iterations
    assert photo == [drop_at(GAMMA, cfg.seed, it, cfg.iterations) for it in range(1, cfg.iterations + 1)]
    by_phase = {}
    for ph, ov, d in calls:
        by_phase.setdefault(ph, []).append((ov, d))
    assert {"hard_render", "soft_render", "warp_render"} <= set(by_phase) and "warp_backward" not in by_phase
    for ph in ("hard_render", "soft_render"):
        assert all(d is None for _, d in by_phase[ph]), ph
    assert all(ov is not None for ov, _ in by_phase["hard_render"])
    warp = [d for ph, _, d in calls if ph == "warp_render"]
    its = range(cfg.loss.view_warp_from, cfg.iterations + 1)
    assert warp == [drop_at(GAMMA, cfg.seed, it, cfg.iterations) for it in its]
# }}}


# {{{ options

def test_options_are_checked():
    assert LossConfig().drop_gamma == 0.0 and RunConfig().drop_gamma is None
    assert RunConfig(drop_gamma=0.2).drop_gamma == 0.2
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="drop_gamma"):
            RunConfig(drop_gamma=bad)
    from reings.cli import build_parser, config_from_args

    c = config_from_args(build_parser().parse_args(["run", "--drop-gamma", "0.3"]))
    assert c.drop_gamma == 0.3
    assert config_from_args(build_parser().parse_args(["run", "--drop-gamma", "none"])).drop_gamma is None


def test_fit_refuses_a_gamma_of_one(case):
    scene, init, cfg = case
    with pytest.raises(ValueError, match="drop_gamma"):
        fit(scene, replace(cfg, loss=replace(cfg.loss, drop_gamma=1.0)), device="reference", init=init, progress=False)


@pytest.mark.parametrize("method, family, kw, want", [
    ("reings", "llff", {}, 0.2), ("reings", "dtu", {}, 0.2),  # the family defaults (reings only)
    ("dngaussian", "dtu", {}, 0.0), ("dngaussian", "llff", {}, 0.0), ("reings", "dtu", {"drop_gamma": 0.0}, 0.0),
    ("reings", "llff", {"drop_gamma": 0.0}, 0.0), ("dngaussian", "dtu", {"drop_gamma": 0.3}, 0.3),
    ("3dgs", "llff", {"drop_gamma": 0.3}, 0.0)])
def test_gamma_reaches_the_fits_of_reings_and_dngaussian(method, family, kw, want):
    from test_recipe_family import _ctx

    from reings.pipeline import DROP_GAMMA_BY_FAMILY, baseline_recipe, drop_gamma_of, run_settings

    assert DROP_GAMMA_BY_FAMILY == {"llff": 0.2, "dtu": 0.2}
    ctx, _ = _ctx(family, method=method, **kw)
    r = ctx.run_recipe(baseline_recipe("dngaussian", 600, 0, family))
    assert r.loss.drop_gamma == want == drop_gamma_of(ctx.cfg, family)
    s = run_settings(ctx.cfg, "dtu" if family == "dtu" else "llff")
    assert s.get("drop_gamma") == (want or None)  # absent when off: older run folders resume


def test_metrics_record_the_gamma_used(tmp_path):
    import reings

    r = reings.run(method="dngaussian", iterations=4, depth_prior="exact", drop_gamma=0.3, quiet=True,
                   with_lpips=False, eval_every=0)
    m = r.metrics
    assert m["drop_gamma"] == 0.3 and m["config"]["drop_gamma"] == 0.3 and m["run_config"]["drop_gamma"] == 0.3
    assert [st["config"]["loss"]["drop_gamma"] for st in m["stages"] if st["iterations"]] == [0.3]
    m0 = reings.run(method="3dgs", iterations=3, depth_prior="none", drop_gamma=0.3, quiet=True, with_lpips=False,
                    eval_every=0).metrics
    assert m0["drop_gamma"] == 0.0 and "drop_gamma" not in m0["config"]
    assert m0["stages"][-1]["config"]["loss"]["drop_gamma"] == 0.0
# }}}


def test_eval_notices_the_family_defaults(tmp_path):
    """A reings run finished without DropGaussian is flagged by `reings eval` now that both
    families drop by default (and LLFF prunes the unseen Gaussians); one finished with the
    defaults is not."""
    import json

    from reings.config import RunConfig
    from reings.evaluate import _settings_differ
    from reings.pipeline import run_settings

    cfg = RunConfig()
    for kind in ("dtu", "llff"):
        now = json.loads(json.dumps(run_settings(cfg.resolved(), kind)))
        old = {k: v for k, v in now.items() if k not in ("drop_gamma", "prune_unseen")}
        for name, config in (("old", old), ("now", now)):
            (tmp_path / kind / name).mkdir(parents=True)
            (tmp_path / kind / name / "metrics.json").write_text(json.dumps({"config": config}))
        assert "drop_gamma" in _settings_differ(str(tmp_path / kind / "old" / "metrics.json"), cfg, kind)
        assert _settings_differ(str(tmp_path / kind / "now" / "metrics.json"), cfg, kind) == ""
    # the DTU defaults (no prune_unseen) are not the LLFF ones
    assert "prune_unseen" in _settings_differ(str(tmp_path / "dtu" / "now" / "metrics.json"), cfg, "llff")
