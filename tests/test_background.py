"""DNGaussian's DTU background rules (reings/background.py; the bg_alpha pass of reings/train.py;
kernels/bg_alpha.cl) against independent references: a brute-force loop for the mask, hand-built
states for the black / white rules, central differences for the alpha term's gradient through
the float64 render, and the device engine against the host engine on a fit with the rules on."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cases import assert_engines_agree, dngaussian_fit_case
from reings.background import dark_background_mask, dark_white_rules, zero_background
from reings.backends import get_backend
from reings.backends.reference import render64
from reings.backends.reference_loss import bg_alpha_fwd_bwd
from reings.state import TrainState
from reings.train import fit
from reings.types import ACCUM, Gaussians


def _brute_mask(im, thr, col):
    h, w, _ = im.shape
    out = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            out[y, x] = all(im[yy, x].max() < thr for yy in range(max(0, y - col), y + 1))
    return out


@pytest.mark.parametrize("shape, col", [((60, 7, 3), 49), ((12, 9, 3), 3), ((5, 4, 3), 0), ((1, 6, 3), 49),
                                        ((70, 1, 3), 49)])
def test_mask_matches_brute_force(shape, col):
    rng = np.random.default_rng(shape[0] * 7 + col)
    for trial in range(4):
        im = rng.uniform(0, 1, shape)
        # dark blocks of random heights, some touching the top edge, some values at the threshold
        for _ in range(3):
            y0 = int(rng.integers(0, shape[0]))
            y1 = int(rng.integers(y0, shape[0] + 1))
            x0 = int(rng.integers(0, shape[1]))
            im[y0:y1, x0:] = rng.uniform(0, 30 / 255, (y1 - y0, shape[1] - x0, 3))
        im[0, 0] = 30 / 255  # exactly the threshold: not dark
        np.testing.assert_array_equal(dark_background_mask(im, 30 / 255, col), _brute_mask(im, 30 / 255, col))
    assert dark_background_mask(np.zeros(shape), 30 / 255, col).all()
    assert not dark_background_mask(np.ones(shape), 30 / 255, col).any()


def test_mask_needs_the_column_above():
    im = np.zeros((100, 2, 3))
    im[40, 0] = 1.0  # one bright pixel in column 0
    m = dark_background_mask(im)
    assert m[:40, 0].all() and not m[40:90, 0].any() and m[90:, 0].all() and m[:, 1].all()
    with pytest.raises(ValueError):
        dark_background_mask(np.zeros((4, 4)))


def test_zero_background():
    im = np.full((3, 4, 3), 0.05, np.float32)
    m = np.zeros((3, 4), bool)
    m[1, 2] = True
    z = zero_background(im, m)
    assert z.dtype == np.float32 and (z[1, 2] == 0).all() and (z[~m] == np.float32(0.05)).all()
    assert (im == np.float32(0.05)).all()  # the input is not modified


def test_dark_white_rules():
    c0 = 0.28209479177387814
    cols = np.array([[0.01, 0.02, 0.05], [0.5, 0.5, 0.5], [0.99, 0.96, 0.97], [0.05, 0.5, 0.01], [0.95, 0.95, 0.9]])
    n = len(cols)
    g = Gaussians(np.zeros((n, 3), np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                  np.zeros((n, 3), np.float32), np.full(n, 2.0, np.float32), ((cols - 0.5) / c0)[:, None, :].astype(np.float32))
    st = TrainState.from_gaussians(g, 0)
    st.stats[ACCUM] = np.full(n, 8.0, np.float32)

    out = dark_white_rules(st)
    assert out == {"black": 1, "white": 1}
    np.testing.assert_array_equal(st.stats[ACCUM], np.float32([0.8, 8, 4, 8, 8]))
    np.testing.assert_allclose(1 / (1 + np.exp(-st.params["opacity_logits"].astype(np.float64))), [0.1, *[1 / (1 + np.exp(-2.0))] * 4],
                               rtol=1e-6)


def test_bg_alpha_twin_and_gradient_fd():
    """The term's gradient to the opacity logits through the float64 render: the host trainer on
    the reference backend against a central difference of mean(alpha^2) over the mask."""
    import reings

    scene = reings.make_procedural_scene(n_views=2, width=24, height=20, supersample=1)
    cam = scene.cameras[0]
    rng = np.random.default_rng(2)
    pts = cam.center + cam.viewmat[2, :3] * rng.uniform(3, 4, (12, 1)) + cam.viewmat[0, :3] * rng.uniform(-1, 1, (12, 1)) \
        + cam.viewmat[1, :3] * rng.uniform(-0.8, 0.8, (12, 1))
    g = Gaussians(pts.astype(np.float32), np.tile(np.float32([1, 0, 0, 0]), (12, 1)), np.full((12, 3), np.log(0.3), np.float32),
                  rng.uniform(-1, 1, 12).astype(np.float32), rng.normal(0, 0.5, (12, 1, 3)).astype(np.float32))
    mask = np.zeros((20, 24), bool)
    mask[:, :10] = True
    tr = get_backend("reference").trainer([scene.images[0]], engine="host")
    tr.upload(TrainState.from_gaussians(g, 0))
    tr.upload_bg_masks([mask])
    fr = tr.forward(cam, 1, (0, 0, 0), 0.01)
    va = tr.bg_alpha(fr, 0)
    loss, v64 = bg_alpha_fwd_bwd(fr.out.alpha, mask)
    np.testing.assert_allclose(va, v64, rtol=1e-6, atol=0)
    gr = tr.backward(fr, None, None, None, ("opacity_logits",), v_alpha=va)
    x0 = np.asarray(g.opacity_logits, np.float64)
    for trial in range(4):
        d = rng.normal(size=12)
        d /= np.linalg.norm(d)
        ends, xs = [], []
        for s in (1, -1):
            gg = Gaussians(g.means, g.quats, g.log_scales, x0 + s * 1e-3 * d, g.sh)
            xs.append(np.asarray(gg.opacity_logits, np.float64))
            ends.append(bg_alpha_fwd_bwd(render64(gg, cam)[2].alpha, mask)[0])
        fd, an = ends[0] - ends[1], float(np.sum(np.asarray(gr["opacity_logits"], np.float64) * (xs[0] - xs[1])))
        assert abs(fd - an) <= 2e-3 * abs(fd) + 1e-9, (fd, an)
    assert loss > 0 and bg_alpha_fwd_bwd(fr.out.alpha, np.zeros_like(mask))[0] == 0.0


@pytest.fixture(scope="module")
def dark_case():
    scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                                           soft_depth_from=3, densify_until=25)
    ims = []
    for im in scene.images:  # a dark band at the top and a dark column: non-empty masks
        im = np.array(im, np.float32)
        im[:12] *= 0.05
        im[:, :6] *= 0.05
        ims.append(im)
    scene = replace(scene, images=ims)
    cfg = replace(cfg, loss=replace(cfg.loss, dark_background=True), densify=replace(cfg.densify, dark_white_rules=True))
    return scene, init, cfg


def test_fit_with_background_rules_device_matches_host(device, dark_case):
    scene, init, cfg = dark_case
    assert dark_background_mask(scene.images[0]).sum() > 500
    kw = dict(device=device, init=init, depth_targets=list(scene.depths), progress=False, log_every=5)
    host = fit(scene, cfg, engine="host", **kw)
    dev = fit(scene, cfg, engine="device", **kw)
    assert [d for _, d in host.history.densify] == [d for _, d in dev.history.densify]
    assert "dark_white" in host.history.densify[0][1]
    assert_engines_agree(device, host.state, dev.state, "background rules")
    off = fit(scene, replace(cfg, loss=replace(cfg.loss, dark_background=False)), engine="device", **kw)
    assert off.state.adam.step["opacity_logits"] < dev.state.adam.step["opacity_logits"]  # the pass steps the opacities


_OCLGRIND_SCRIPT = """
import types
import numpy as np
import pyopencl as cl
from reings.backends import get_backend
from reings.backends.reference_state import opacity_decay_
from reings.state import TrainState
from reings.types import Gaussians
n = 7
logits = np.array([0.0, np.nan, np.inf, -np.inf, 1e30, -1e30, 3.0], np.float32)
g = Gaussians(np.zeros((n, 3), np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)), np.zeros((n, 3), np.float32),
              logits, np.zeros((n, 1, 3), np.float32))
tr = get_backend("oclgrind").trainer([np.zeros((6, 8, 3), np.float32)], engine="device")
tr.upload(TrainState.from_gaussians(g, 0))
tr.opacity_decay(0.995)
got = tr.read_params(("opacity_logits",))["opacity_logits"]
want = logits.copy()
opacity_decay_(want, 0.995)
fin = np.isfinite(want)
assert np.array_equal(np.isnan(got), np.isnan(want)) and np.allclose(got[fin], want[fin], rtol=1e-6)
# bg_alpha on a frame whose alpha buffer is given (the rasterizer is not under test here)
rng = np.random.default_rng(0)
alpha = rng.uniform(0, 1, (6, 8)).astype(np.float32)
mask = np.zeros((6, 8), bool)
mask[:, :3] = True
tr.upload_bg_masks([mask])
abuf = cl.Buffer(tr.handle.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=alpha)
fr = types.SimpleNamespace(width=8, height=6, bufs={"out_alpha": abuf})
v = tr._read(tr.bg_alpha(fr, 0), (6, 8), np.float32)
assert np.array_equal(v, np.where(mask, np.float32(2.0 / 18) * alpha, np.float32(0)))
print("ok")
"""


@pytest.mark.oclgrind
def test_oclgrind_checks():
    """bg_alpha_grad and opacity_decay (with poisoned logits) under Oclgrind's checks (project_bwd's
    accumulate mode, which replaced grad_add_multi, is checked in tests/test_project.py)."""
    from oclgrind_util import check_script

    check_script(_OCLGRIND_SCRIPT)
