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
count, or a wrong group still fails."""
from __future__ import annotations

import os

import numpy as np
import pytest

from cases import dngaussian_fit_case, interrupt_and_resume
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


def test_engine_choice(case):
    scene, init, cfg = case
    with pytest.raises(ValueError, match="OpenCL"):
        fit(scene, cfg, device="reference", init=init, engine="device", progress=False)
    with pytest.raises(ValueError, match="engine"):
        fit(scene, cfg, device="reference", init=init, engine="gpu", progress=False)
