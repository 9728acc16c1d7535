"""The gsplat-comparable training step of the device engine (DeviceTrainer.step_l1, bench/peer_step.py):

  * the L1-only photometric kernels (kernels/l1.cl) against the float64 reference l1_fwd_bwd;
  * two steps of step_l1 against the host path (render -> photometric_loss with lambda 0 ->
    render_vjp -> numpy Adam, the host engine's photometric pass): parameters and moments
    bit-identical on PoCL (same kernels; Adam kernel in numpy's operation order), float32 rounding
    elsewhere (see tests/test_device_fit.py);
  * host syncs per step (one blocking read: the binning's (V, K), none with the sync-free binning
    of docs/perf_notes.md §8; one more only for read_loss);
  * bench/peer_step.py imports and runs without torch (gsplat side skipped).
"""
from __future__ import annotations

import numpy as np
import pytest

from cases import binning
from reings.backends import get_backend
from reings.backends import reference_loss as RL
from reings.backends.opencl import quirks
from reings.backends.opencl.harness import ClCalls
from reings.bench import make_step_trainer
from reings.bench_scenes import perf_scene
from reings.optim import Adam
from reings.state import PARAM_NAMES, TrainState

pytest.importorskip("pyopencl")


def _case(sh=1, n=400, w=48, h=40):
    """Scene B's Gaussians (n of them) seen by a small camera with a short focal length."""
    from reings.types import Camera

    g, _ = perf_scene("B", sh_degree=sh, n=n, seed=3)
    f = 100.0
    cc = Camera(np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]), np.eye(4), w, h)
    target = np.random.default_rng(5).uniform(0, 1, (cc.height, cc.width, 3)).astype(np.float32)
    return g, cc, target


@pytest.mark.parametrize("hw", [(7, 5), (40, 33), (1, 1)])
def test_l1_kernels_match_reference(device, hw):
    h, w = hw
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    y = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    x.reshape(-1)[::4] = y.reshape(-1)[::4]  # ties: sign 0
    t, _ = make_step_trainer(get_backend(device), perf_scene("A", n=8)[0], y)
    xb = t.mem.get("pixel", "test_x", h * w, 12)
    vb = t.mem.get("pixel", "test_v", h * w, 12)
    t._write(xb, x)
    t.photometric_l1(xb, t.gt[0], vb, h, w, w_l1=0.75)
    loss = t.read_loss()
    v = t._read(vb, (h, w, 3), np.float32)
    ref_loss, ref_v = RL.l1_fwd_bwd(x, y)
    np.testing.assert_array_equal(v, (0.75 * ref_v).astype(np.float32))
    assert loss == pytest.approx(0.75 * ref_loss, rel=1e-6)


def test_l1_step_matches_host_path(device):
    be = get_backend(device)
    g, cam, target = _case()
    lr = 1e-3
    # host path: the host engine's photometric pass with lambda_dssim = 0, numpy Adam
    from reings.losses import photometric_loss

    st = TrainState.from_gaussians(g)
    opt = Adam(st.params, {k: lr for k in PARAM_NAMES}, state=st.adam, eps=1e-15)
    host_losses = []
    for _ in range(2):
        gg = st.gaussians()
        out = be.render(gg, cam)
        loss, v_rgb = photometric_loss(out.rgb, target, 0.0, "dngaussian", device)
        host_losses.append(loss)
        opt.step(st.grads(be.render_vjp(gg, cam, v_rgb)))
    # device engine
    t, dopt = make_step_trainer(be, g, target, lr=lr)
    dev_losses = []
    for _ in range(2):
        fr, loss = t.step_l1(cam, 0, dopt, read_loss=True)
        dev_losses.append(loss)
    assert fr.visible > 50 and fr.isects > fr.visible, "the case must render something"
    dst = TrainState.from_gaussians(g)
    t.download(dst)
    assert dopt.state.step == opt.state.step
    np.testing.assert_allclose(dev_losses, host_losses, rtol=1e-6)
    exact = quirks.is_pocl(be.handle.device)
    for k in PARAM_NAMES:
        for what, a, b in (("param", dst.params[k], st.params[k]), ("exp_avg", dst.adam.exp_avg[k], st.adam.exp_avg[k]),
                           ("exp_avg_sq", dst.adam.exp_avg_sq[k], st.adam.exp_avg_sq[k])):
            if exact:
                np.testing.assert_array_equal(a, b, err_msg=f"{what}/{k}")
            else:
                np.testing.assert_allclose(a, b, rtol=1e-5, atol=2e-6, err_msg=f"{what}/{k}")
    # the step moved every group (sh_rest included: SH degree 1 is fully active)
    for k in PARAM_NAMES:
        assert np.abs(dst.params[k] - TrainState.from_gaussians(g).params[k]).max() > 0, k


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_step_host_syncs(device, mode):
    be = get_backend(device)
    g, cam, target = _case(sh=0)
    counts = {"sync": 1, "async": 0}[mode]  # the binning's blocking read of (V, K)
    with binning(be, mode) as done:
        t, opt = make_step_trainer(be, g, target)
        t.step_l1(cam, 0, opt)
        be.queue.finish()
        with ClCalls() as c:
            t.step_l1(cam, 0, opt)
        n = c.n
        assert n["reads_blocking"] == counts, n  # nothing else
        assert n["writes_blocking"] == n["maps_blocking"] == n["finishes"] == n["waits"] == 0, n
        assert n["copies"] == 1, n  # the counts' read only: no per-step upload (camera records are cached)
        assert n["launches"] >= 15, n
        with ClCalls() as c2:
            t.step_l1(cam, 0, opt, read_loss=True)
        assert c2.n["reads_blocking"] == counts + 1 and c2.n["launches"] == n["launches"] + 1  # + l1_total
    assert done[mode] == 3


def _load_peer_step():
    from cases import load_bench

    return load_bench("peer_step")


def test_peer_step_runs_without_gsplat(device, capsys, tmp_path):
    ps = _load_peer_step()
    out = tmp_path / "rows.jsonl"
    assert ps.main(["--device", device, "--scenes", "A", "--sh", "0", "--n", "300", "--warmup", "1",
                    "--repeats", "2", "--ref-crop", "16", "--no-gsplat", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "gsplat side skipped" in text and "max|ours - f64|" in text
    import json

    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 1 and rows[0]["ours_step_wall_ms"] > 0 and rows[0]["max_err_rgb_vs_f64"] < 1e-4
    r = ps.overhead(get_backend(device), size=16, n=200, sh=0, steps=2, rounds=1)
    syncs = 1 if be_mode(device) == "sync" else 0  # the binning's read of (V, K) (docs/perf_notes.md §8)
    assert r["per_step"]["syncs"] == syncs and r["python_us_launches_stubbed"] > 0


def be_mode(device) -> str:
    """How the backend bins the overhead case (16x16: one tile, 200 Gaussians)."""
    return get_backend(device).binning(200, 1)
