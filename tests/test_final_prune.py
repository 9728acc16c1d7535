"""ReInGSConfig.final_prune and run(prune_curve=True): the Omega_G helper shared with CVPS, the
deterministic top-k keep against an independent float64 Omega_G, the CLI flags, and short
end-to-end runs (counts before/after, the curve, resume applying the prune exactly once)."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from cases import make_camera, make_gaussians, rotation_viewmat

import reings
from reings import pipeline, reinit
from reings.backends import reference
from reings.backends.base import ALPHA_MAX, ALPHA_MIN, EPS2D, T_MIN
from reings.cli import build_parser, main
from reings.config import ReInGSConfig
from reings.reinit import cvps_select, gaussian_importance, prune_keep_indices
from reings.rendering import render

BG, NEAR = (0.0, 0.0, 0.0), 0.01
W = H = 16  # one tile: no tile-rect culling, so the plain per-pixel loop below is the whole definition


def _tiny_scene():
    """Eight isotropic Gaussians at distinct depths (no sort ties), all projecting inside a 16 x 16
    image of each of three cameras; opacities and sizes spread so that Omega_G is well separated."""
    means = np.array([[-0.5, -0.4, 3.0], [0.45, -0.35, 3.4], [-0.3, 0.45, 2.6], [0.35, 0.3, 3.8],
                      [0.0, 0.0, 3.2], [-0.55, 0.05, 4.1], [0.5, 0.0, 2.9], [0.05, -0.5, 3.6]])
    log_s = np.log([0.35, 0.15, 0.25, 0.45, 0.3, 0.2, 0.1, 0.4])
    logits = np.array([1.5, 0.2, -0.8, 2.0, -1.5, 0.7, 3.0, -0.3])
    g = make_gaussians(means, log_scales=np.repeat(log_s[:, None], 3, 1), opacity_logits=logits, seed=1)
    cams = [make_camera(W, H),
            make_camera(W, H, viewmat=rotation_viewmat((0.03, -0.05, 0.02), (0.1, 0.0, 0.1))),
            make_camera(W, H, viewmat=rotation_viewmat((-0.04, 0.06, -0.03), (-0.1, 0.05, -0.1)))]
    return g, cams


def omega_reference(g, cams) -> np.ndarray:
    """Omega_G = sum over views and pixels of alpha_i * T_i, float64, written out independently for
    isotropic Gaussians (camera-space covariance s^2 I; EWA Jacobian; 3DGS conventions: +EPS2D on
    the 2D covariance, alpha = min(ALPHA_MAX, o exp(power)), skip alpha < ALPHA_MIN, stop before the
    Gaussian that would take T below T_MIN, pixel centres at +0.5)."""
    means = np.asarray(g.means, np.float64)
    s2 = np.exp(2 * np.asarray(g.log_scales, np.float64)[:, 0])
    o = 1 / (1 + np.exp(-np.asarray(g.opacity_logits, np.float64)))
    omega = np.zeros(len(means))
    for cam in cams:
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        X = means @ R.T + t
        z = X[:, 2]
        order = np.argsort(z, kind="stable")
        u, v = cam.fx * X[:, 0] / z + cam.cx, cam.fy * X[:, 1] / z + cam.cy
        conics = []
        for k in range(len(means)):
            J = np.array([[cam.fx / z[k], 0, -cam.fx * X[k, 0] / z[k] ** 2],
                          [0, cam.fy / z[k], -cam.fy * X[k, 1] / z[k] ** 2]])
            conics.append(np.linalg.inv(s2[k] * J @ J.T + EPS2D * np.eye(2)))
        for py in range(cam.height):
            for px in range(cam.width):
                T = 1.0
                for k in order:
                    d = np.array([u[k] - (px + 0.5), v[k] - (py + 0.5)])
                    a = min(ALPHA_MAX, o[k] * np.exp(-0.5 * d @ conics[k] @ d))
                    if a < ALPHA_MIN:
                        continue
                    if T * (1 - a) < T_MIN:
                        break
                    omega[k] += a * T
                    T *= 1 - a
    return omega


@pytest.fixture(scope="module")
def tiny():
    g, cams = _tiny_scene()
    return g, cams, omega_reference(g, cams)


def test_reference_scene_is_well_posed(tiny):
    g, cams, om = tiny
    assert np.all(om > 0), om  # every Gaussian is seen
    s = np.sort(om)
    assert np.min(np.diff(s) / s[1:]) > 1e-2, s  # float32 cannot reorder the ranking
    # the independent loop is the reference backend's definition too
    ref = sum(reference.render64(g, c, BG, NEAR, want_importance=True)[2].importance for c in cams)
    np.testing.assert_allclose(ref, om, rtol=1e-10, atol=1e-12)


def test_importance_helper_is_cvps_basis(tiny, device, monkeypatch):
    g, cams, om = tiny
    omega = gaussian_importance(g, cams, device, BG, NEAR)
    assert omega.dtype == np.float64 and omega.shape == (len(g),)
    manual = np.zeros(len(g))
    for c in cams:
        manual += render(g, c, device, BG, NEAR, want_importance=True).importance
    np.testing.assert_array_equal(omega, manual)
    np.testing.assert_allclose(omega, om, rtol=1e-4, atol=1e-6)
    # cvps_select draws with p ~ this omega (+ its epsilon): same seed, same draw
    rc = ReInGSConfig(cvps_fraction=0.5)
    train = SimpleNamespace(cameras=cams)
    sel = cvps_select(g, train, rc, device, BG, NEAR, np.random.default_rng(5))
    p = omega + 1e-12 * max(omega.max(), 1.0)
    want = np.sort(np.random.default_rng(5).choice(len(g), size=4, replace=False, p=p / p.sum()))
    np.testing.assert_array_equal(sel, want)
    # and it goes through the helper (no second copy of the loop): a fake Omega_G steers it
    fake = np.zeros(len(g))
    fake[[1, 4, 6, 7]] = 1.0
    monkeypatch.setattr(reinit, "gaussian_importance", lambda *a, **k: fake)
    np.testing.assert_array_equal(cvps_select(g, train, rc, device, BG, NEAR, np.random.default_rng(0)), [1, 4, 6, 7])


@pytest.mark.parametrize("f", [0.0, 0.25, 0.5, 0.6, 0.75, 0.875])
def test_prune_keeps_the_top_omega(tiny, device, f):
    g, cams, om = tiny
    n = len(g)
    keep = prune_keep_indices(gaussian_importance(g, cams, device, BG, NEAR), 1.0 - f)
    assert len(keep) == round((1 - f) * n)
    assert np.all(np.diff(keep) > 0)  # sorted, unique
    np.testing.assert_array_equal(keep, np.sort(np.argsort(-om)[:len(keep)]))
    assert om[keep].min() > np.delete(om, keep).max(initial=-1.0)
    pruned = g.subset(keep)
    assert len(pruned) == len(keep)
    np.testing.assert_array_equal(pruned.means, np.asarray(g.means)[keep])


def test_prune_ties_and_edges():
    om = np.array([1.0, 3.0, 2.0, 3.0, 2.0, 0.0, 2.0])
    np.testing.assert_array_equal(prune_keep_indices(om, 3 / 7), [1, 2, 3])  # 2.0 tie: lowest index
    np.testing.assert_array_equal(prune_keep_indices(om, 4 / 7), [1, 2, 3, 4])
    np.testing.assert_array_equal(prune_keep_indices(om, 1.0), np.arange(7))
    np.testing.assert_array_equal(prune_keep_indices(om, 0.01), [1])  # at least one
    assert prune_keep_indices(np.zeros(0), 0.5).shape == (0,)
    for bad in (0.0, -0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="keep"):
            prune_keep_indices(om, bad)


@pytest.mark.parametrize("bad", ["1", "1.0", "1.5", "-0.1", "nan", "inf", "abc", ""])
def test_cli_refuses_bad_final_prune(bad, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:
        main(["run", "--final-prune", bad, "--out", str(out), "--quiet"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--final-prune" in err and ("[0, 1)" in err or "expected a number" in err), err
    assert not out.exists()


def test_run_refuses_bad_final_prune(tmp_path):
    for bad in (1.0, -0.2, 2, float("nan"), "0.5", True):
        with pytest.raises(ValueError, match="final_prune"):
            reings.run(out=str(tmp_path / "out"), reings_config=ReInGSConfig(final_prune=bad), quiet=True)
    assert not (tmp_path / "out").exists()


def test_cli_wires_the_flags(tmp_path, monkeypatch):
    from reings.cli import config_from_args

    c = config_from_args(build_parser().parse_args(["run", "--out", "x"]))
    assert c.reings.final_prune == 0.1 and c.output.prune_curve is False  # the default (model-size study)
    seen = {}

    def fake_run(config, **kw):
        seen["config"] = config
        return pipeline.RunResult(None, {"mean": {"psnr": 1.0}, "method": "reings", "data": "procedural",
                                         "views": 3, "device": "pocl", "seconds": {"method": 0.0, "total": 0.0},
                                         "gaussians": {}})

    monkeypatch.setattr(pipeline, "run", fake_run)
    assert main(["run", "--final-prune", "0.3", "--prune-curve", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    assert seen["config"].reings.final_prune == 0.3 and seen["config"].output.prune_curve is True
    assert main(["run", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    assert seen["config"].reings.final_prune == 0.1 and seen["config"].output.prune_curve is False


class _InterruptEvaluate:
    """pipeline.score_test_views that raises KeyboardInterrupt at its first call (after the final stage)."""

    def __init__(self):
        self.real = pipeline.score_test_views

    def __call__(self, *a, **k):
        raise KeyboardInterrupt


def test_run_final_prune_counts_curve_and_resume(tmp_path, monkeypatch):
    kw = dict(method="reings", iterations=10, depth_prior="exact", quiet=True, with_lpips=False, eval_every=5,
              checkpoint_every=5, device="pocl", seed=2, reings_config=ReInGSConfig(final_prune=0.5),
              prune_curve=True)
    ref = reings.run(out=str(tmp_path / "ref"), **kw)
    m = json.loads((tmp_path / "ref" / "metrics.json").read_text())
    st = m["stages"][-1]
    assert [s["stage"] for s in m["stages"]] == ["ehps", "coarse", "ivps", "fine", "cvps", "final", "final_prune"]
    n0 = m["gaussians"]["final"]
    assert st["gaussians_before"] == n0 == m["stages"][-2]["gaussians"]
    assert st["gaussians"] == m["gaussians"]["final_prune"] == round(0.5 * n0) == len(ref.gaussians)
    assert m["reings_config"]["final_prune"] == 0.5 and m["seconds"]["final_prune"] >= 0
    assert m["model_bytes"]["final_prune"] == pipeline.gaussians_nbytes(ref.gaussians)
    assert m["psnr_vs_time"]["points"][-1]["stage"] == "final_prune"
    assert m["psnr_vs_time"]["points"][-1]["psnr"] == pytest.approx(m["mean"]["psnr"], abs=1e-6)
    curve = m["prune_curve"]
    assert [c["keep"] for c in curve] == [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4]
    ns = [c["gaussians"] for c in curve]
    assert ns[0] == n0 and all(a >= b for a, b in zip(ns, ns[1:])) and ns[-1] == round(0.4 * n0)
    assert all(c["psnr"] is not None and c["ssim"] is not None for c in curve)
    # the keep = 0.5 point of the curve is the reported (pruned) model
    assert curve[5]["gaussians"] == len(ref.gaussians)
    assert curve[5]["psnr"] == pytest.approx(m["mean"]["psnr"]) and curve[5]["ssim"] == pytest.approx(m["mean"]["ssim"])

    # interrupted after the final stage (in the curve's first evaluation), then resumed: the final
    # stage comes back from final.npz (the unpruned model) and the prune is applied once, identically
    out = tmp_path / "cut"
    monkeypatch.setattr(pipeline, "score_test_views", _InterruptEvaluate())
    with pytest.raises(KeyboardInterrupt):
        reings.run(out=str(out), **kw)
    monkeypatch.undo()
    assert not (out / "metrics.json").exists()
    with np.load(out / "checkpoints" / "final.npz") as z:
        assert len(z["param/means"]) == n0
    res = reings.run(out=str(out), **kw)
    assert res.metrics["gaussians"] == ref.metrics["gaussians"]
    assert res.metrics["stages"][-1]["gaussians"] == st["gaussians"]
    np.testing.assert_array_equal(res.gaussians.means, ref.gaussians.means)
    for k in ("psnr", "ssim"):
        assert res.metrics["mean"][k] == ref.metrics["mean"][k], k
    assert res.metrics["prune_curve"] == ref.metrics["prune_curve"]
