"""numpy Adam (float32, in place) against a float64 step-by-step reference of torch.optim.Adam's
update; per-group step counts; schedules."""
from __future__ import annotations

import math

import numpy as np
import pytest

from reings.optim import Adam, expon_lr, held_expon_lr, position_lr, sh_degree_at
from reings.config import preset


def _ref_adam(p, grads, lr, t0=0, b1=0.9, b2=0.999, eps=1e-15, m=None, v=None):
    """float64 torch.optim.Adam, one parameter, a sequence of gradients."""
    p = p.astype(np.float64).copy()
    m = np.zeros_like(p) if m is None else m.copy()
    v = np.zeros_like(p) if v is None else v.copy()
    t = t0
    for g in grads:
        g = g.astype(np.float64)
        t += 1
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        denom = np.sqrt(v) / math.sqrt(1 - b2 ** t) + eps
        p = p - lr / (1 - b1 ** t) * m / denom
    return p, m, v


def test_adam_matches_float64_reference(rng):
    params = {"a": rng.normal(size=(50, 3)).astype(np.float32), "b": rng.normal(size=(50,)).astype(np.float32)}
    p0 = {k: v.copy() for k, v in params.items()}
    opt = Adam(params, {"a": 0.01, "b": 0.05}, eps=1e-15)
    ga = [rng.normal(size=(50, 3)).astype(np.float32) * 10 ** rng.uniform(-4, 1) for _ in range(20)]
    gb = [rng.normal(size=(50,)).astype(np.float32) for _ in range(20)]
    a_id = id(params["a"])
    for i in range(20):
        opt.step({"a": ga[i], "b": gb[i]})
    assert id(params["a"]) == a_id  # in place
    ra, ma, va = _ref_adam(p0["a"], ga, 0.01)
    rb, _, _ = _ref_adam(p0["b"], gb, 0.05)
    np.testing.assert_allclose(params["a"], ra, rtol=0, atol=2e-6)
    np.testing.assert_allclose(params["b"], rb, rtol=0, atol=2e-6)
    # float32 rounding relative to the moment scale (m mixes gradients of very different sizes)
    np.testing.assert_allclose(opt.state.exp_avg["a"], ma, rtol=1e-5, atol=1e-6 * np.abs(ma).max())
    np.testing.assert_allclose(opt.state.exp_avg_sq["a"], va, rtol=1e-5, atol=1e-6 * va.max())
    assert params["a"].dtype == np.float32 and opt.state.exp_avg["a"].dtype == np.float32
    assert opt.state.step == {"a": 20, "b": 20}


def test_separate_step_counts_per_group(rng):
    """DNGaussian: means stepped 3x per iteration, others once; bias corrections follow each count."""
    params = {"means": rng.normal(size=(10, 3)).astype(np.float32), "sh": rng.normal(size=(10, 1, 3)).astype(np.float32)}
    p0 = {k: v.copy() for k, v in params.items()}
    opt = Adam(params, {"means": 1e-3, "sh": 2.5e-3})
    gm, gs = [], []
    for it in range(5):
        for _ in range(2):  # hard and soft depth passes: means only
            g = rng.normal(size=(10, 3)).astype(np.float32)
            gm.append(g)
            opt.step({"means": g})
        g = rng.normal(size=(10, 3)).astype(np.float32)
        g2 = rng.normal(size=(10, 1, 3)).astype(np.float32)
        gm.append(g)
        gs.append(g2)
        opt.step({"means": g, "sh": g2, "unused": None}, groups=["means", "sh"])
    assert opt.state.step == {"means": 15, "sh": 5}
    np.testing.assert_allclose(params["means"], _ref_adam(p0["means"], gm, 1e-3)[0], atol=2e-6)
    np.testing.assert_allclose(params["sh"], _ref_adam(p0["sh"], gs, 2.5e-3)[0], atol=2e-6)


def test_groups_argument_and_errors(rng):
    params = {"a": np.zeros(4, np.float32), "b": np.zeros(4, np.float32)}
    opt = Adam(params, {"a": 0.1, "b": 0.1})
    opt.step({"a": np.ones(4), "b": np.ones(4)}, groups=["a"])
    assert opt.state.step == {"a": 1, "b": 0}
    assert np.all(params["b"] == 0) and np.allclose(params["a"], -0.1)
    with pytest.raises(ValueError, match="shape"):
        opt.step({"a": np.ones(5)})
    with pytest.raises(KeyError):
        opt.step({"c": np.ones(4)})
    with pytest.raises(ValueError, match="unknown"):
        Adam(params, {"zz": 1.0})


def test_zero_size_and_schedule_hook(rng):
    params = {"rest": np.zeros((3, 0, 3), np.float32), "x": np.ones(2, np.float32)}
    opt = Adam(params, {"rest": 1e-3, "x": 1.0}, schedules={"x": lambda it: 0.5 ** it})
    opt.step({"rest": np.zeros((3, 0, 3)), "x": np.zeros(2)})
    opt.update_learning_rate(3)
    assert opt.lr["x"] == 0.125


def test_expon_schedules():
    # 3DGS: log-linear from init to final over max_steps
    assert expon_lr(0, 1e-2, 1e-4, 100) == pytest.approx(1e-2)
    assert expon_lr(50, 1e-2, 1e-4, 100) == pytest.approx(1e-3)
    assert expon_lr(100, 1e-2, 1e-4, 100) == pytest.approx(1e-4)
    assert expon_lr(10_000, 1e-2, 1e-4, 100) == pytest.approx(1e-4)
    # DNGaussian: held for 500 its, then decays over 5500
    for it in (0, 1, 250, 500):
        assert held_expon_lr(it, 0.016, 0.00016, 5500, start=500) == pytest.approx(0.016)
    assert held_expon_lr(500 + 2750, 0.016, 0.00016, 5500, start=500) == pytest.approx(0.0016)
    assert held_expon_lr(6000, 0.016, 0.00016, 5500, start=500) == pytest.approx(0.00016)
    c = preset("dngaussian").optim
    assert position_lr(6000, c, extent=2.0) == pytest.approx(0.00032)
    assert position_lr(1, c, extent=2.0) == pytest.approx(0.032)
    # delay term (3DGS option)
    assert expon_lr(0, 1.0, 1.0, 10, delay_steps=10, delay_mult=0.01) == pytest.approx(0.01)
    assert [sh_degree_at(i, 3) for i in (1, 999, 1000, 2500, 9000)] == [0, 0, 1, 2, 3]
