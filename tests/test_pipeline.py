"""`reings.run`: training helps, PSNR-vs-seconds series and SVG, outputs, resume, refusals."""
from __future__ import annotations

import dataclasses
import json
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import reings
from reings import pipeline
from reings.config import (FIT_STAGES, STAGES, OutputConfig, ReInGSConfig, RunConfig, load_run_config, method_label,
                           parse_method)
from reings.cli import main
from reings.outputs import psnr_time_svg


def test_parse_method_and_label():
    assert parse_method("dngaussian")[0] == "dngaussian"
    base, rc = parse_method("reings")
    assert base == "reings" and rc.ehps and rc.ivps and rc.cvps
    base, rc = parse_method("reings-no-ivps-no-cvps")
    assert (rc.ehps, rc.ivps, rc.cvps) == (True, False, False)
    assert method_label(*parse_method("reings-no-cvps-no-ehps")) == "reings-no-ehps-no-cvps"
    assert method_label("reings", ReInGSConfig(ivps=False)) == "reings-no-ivps"
    assert method_label("dngaussian", ReInGSConfig(ivps=False)) == "dngaussian"
    for bad in ("foo", "reings-no-foo", "reings-no-ehps-no-ehps", "reings-ehps", ""):
        with pytest.raises(ValueError, match="unknown method"):
            parse_method(bad)


def test_svg_is_well_formed_with_stage_marks():
    pts = [{"seconds": 0.0, "psnr": 12.0}, {"seconds": 1.5, "psnr": 14.0}, {"seconds": 3.0, "psnr": 13.5},
           {"seconds": 4.0, "psnr": 16.25}]
    bounds = [{"stage": "coarse", "start": 0.0, "end": 1.6}, {"stage": "fine", "start": 1.7, "end": 3.1},
              {"stage": "final", "start": 3.2, "end": 4.0}]
    root = ET.fromstring(psnr_time_svg(pts, bounds, "a <title> & more"))
    ns = "{http://www.w3.org/2000/svg}"
    (poly,) = root.iter(ns + "polyline")
    assert len(poly.get("points").split()) == 4
    texts = [t.text for t in root.iter(ns + "text")]
    assert {"coarse", "fine", "final"} <= set(texts)
    assert "test PSNR (dB)" in texts and "a <title> & more" in texts
    dashed = [e for e in root.iter(ns + "line") if e.get("stroke-dasharray")]
    assert len(dashed) == 2  # the boundaries between the three stages
    xs = [float(v.split(",")[0]) for v in poly.get("points").split()]
    assert xs == sorted(xs) and 0 <= min(xs) and max(xs) <= float(root.get("width"))


def test_short_fit_raises_test_psnr(tmp_path):
    """dngaussian for 100 iterations on the procedural scene beats its initial Gaussians on the
    held-out views by a clear margin; metrics.json and the SVG carry the series."""
    out = tmp_path / "run"
    r = reings.run(method="dngaussian", iterations=100, depth_prior="exact", out=str(out), quiet=True,
                   with_lpips=False, eval_every=50, device="pocl")
    pts = r.metrics["psnr_vs_time"]["points"]
    assert [p["stage"] for p in pts] == ["init", "dngaussian", "dngaussian"]
    assert [p["iteration"] for p in pts] == [0, 50, 100]
    init_psnr, final_psnr = pts[0]["psnr"], r.metrics["mean"]["psnr"]
    assert final_psnr > init_psnr + 2.0, (init_psnr, final_psnr)
    assert pts[-1]["psnr"] == pytest.approx(final_psnr, abs=1e-6)  # the probe = the final evaluation's PSNR
    secs = [p["seconds"] for p in pts]
    assert secs == sorted(secs) and secs[-1] > 0
    assert all(p["wall_seconds"] >= p["seconds"] - 1e-9 for p in pts)
    assert [s["stage"] for s in r.metrics["stages"]] == ["init", "dngaussian"]
    st = r.metrics["stages"][1]
    assert st["eval_seconds"] > 0 and st["wall_seconds"] >= st["seconds"]
    assert r.metrics["seconds"]["method"] == pytest.approx(st["seconds"])
    # outputs
    m = json.loads((out / "metrics.json").read_text())
    assert m["mean"]["psnr"] == pytest.approx(final_psnr)
    assert m["gaussians"]["dngaussian"] == len(r.gaussians) == st["gaussians"]
    assert m["model_bytes"]["dngaussian"] == pipeline.gaussians_nbytes(r.gaussians) > 0
    assert m["memory"]["peak_rss_mb"] > 0 and m["memory"]["device_peak_bytes"] > 0
    kb = m["kernel_builds"]  # this process's builds during the run; the fit's share on its stage entry
    assert kb["programs"] >= st["kernel_builds"]["programs"] >= 0 and kb["seconds"] >= st["kernel_builds"]["seconds"] >= 0
    b = m["memory"]["binning"]  # PoCL bins in sync unless REINGS_BIN says otherwise
    assert b["mode"] in ("auto", "sync", "async") and b["sync"] + b["async"] > 0
    assert m["config"]["iterations"] == [100] and m["config"]["method"] == "dngaussian"
    assert m["stages"][1]["config"]["iterations"] == 100 and m["stages"][1]["config"]["seed"] == 0
    # the resolved configuration next to metrics.json, and in it
    want = RunConfig(method="dngaussian", iterations=(100,), depth_prior="exact", sh_degree=0,
                     output=OutputConfig(out=str(out), lpips=False, eval_every=50))
    assert load_run_config(out / "config.toml") == want
    assert m["run_config"] == json.loads(json.dumps(dataclasses.asdict(want)))
    ET.parse(out / "psnr_vs_time.svg")
    assert (out / "gaussians.ply").is_file() and len(os.listdir(out / "renders")) == len(m["test_names"])
    # a second run into the same folder is refused, before any work
    with pytest.raises(FileExistsError, match="already holds a finished run"):
        reings.run(method="dngaussian", iterations=100, depth_prior="exact", out=str(out), quiet=True)
    # eval_every=0: no probes, no SVG
    r0 = reings.run(method="dngaussian", iterations=10, depth_prior="exact", out=str(tmp_path / "r0"), quiet=True,
                    with_lpips=False, eval_every=0)
    assert r0.metrics["psnr_vs_time"]["points"] == [] and not (tmp_path / "r0" / "psnr_vs_time.svg").exists()


class _Interrupt:
    """test_psnr that raises KeyboardInterrupt at its n-th call (as Ctrl-C would mid-fit)."""

    def __init__(self, n):
        self.n, self.calls, self.real = n, 0, pipeline.test_psnr

    def __call__(self, *a, **k):
        self.calls += 1
        if self.calls == self.n:
            raise KeyboardInterrupt
        return self.real(*a, **k)


def test_stage_list_is_the_config_s():
    for method, names in STAGES.items():
        assert [n for n, _ in pipeline.stages_of(method)] == list(names)
        fits = [n for n in names if n in FIT_STAGES[method]]
        assert fits == list(FIT_STAGES[method])


def test_interrupted_run_resumes_to_the_same_result(tmp_path, monkeypatch):
    kw = dict(method="reings", iterations=10, depth_prior="exact", quiet=True, with_lpips=False, eval_every=3,
              checkpoint_every=4, checkpoint_seconds=0, device="pocl", seed=3)
    ref = reings.run(out=str(tmp_path / "ref"), **kw)
    # one name per stage: the stage list, the metrics keys, the fits' configs (with the run's seed)
    m = ref.metrics
    assert [s["stage"] for s in m["stages"]] == list(STAGES["reings"])
    assert all(n in m["gaussians"] and n in m["seconds"] and n in m["model_bytes"] for n in STAGES["reings"])
    assert [s["stage"] for s in m["stages"] if "config" in s] == list(FIT_STAGES["reings"])
    assert [s["config"]["seed"] for s in m["stages"] if "config" in s] == [3, 3, 3]
    assert m["gaussians"]["init"] == m["gaussians"]["ehps"]

    out = tmp_path / "cut"
    # probes: init, coarse 3/6/9/10, fine 3/6/9 <- interrupted there; fine's last checkpoint is at 8
    monkeypatch.setattr(pipeline, "test_psnr", _Interrupt(8))
    with pytest.raises(KeyboardInterrupt):
        reings.run(out=str(out), **kw)
    assert not (out / "metrics.json").exists()
    assert (out / "checkpoints" / "coarse.npz").exists() and (out / "checkpoints" / "fine.npz").exists()
    assert not (out / "checkpoints" / "final.npz").exists()
    monkeypatch.undo()

    # other settings into the interrupted folder are refused
    with pytest.raises(ValueError, match="interrupted run with other settings") as refused:
        reings.run(out=str(out), **{**kw, "iterations": 12})
    assert "iterations: [10, 10, 10] there, [12, 12, 12] now" in str(refused.value)  # the values, both sides
    res = reings.run(out=str(out), **kw)
    for k in ("psnr", "ssim"):
        assert res.metrics["mean"][k] == ref.metrics["mean"][k], k
    assert res.metrics["gaussians"] == ref.metrics["gaussians"]
    np.testing.assert_array_equal(res.gaussians.means, ref.gaussians.means)
    a = [(p["stage"], p["iteration"], p["psnr"]) for p in res.metrics["psnr_vs_time"]["points"]]
    b = [(p["stage"], p["iteration"], p["psnr"]) for p in ref.metrics["psnr_vs_time"]["points"]]
    assert a == b
    assert json.loads((out / "metrics.json").read_text())["mean"] == res.metrics["mean"]
    # --overwrite starts over (checkpoints removed) and gives the same result again
    again = reings.run(out=str(out), overwrite=True, **kw)
    assert again.metrics["mean"] == res.metrics["mean"]


def test_config_toml_reproduces_the_run(tmp_path, capsys):
    """`reings run --config A/config.toml --out B` is the same run as A (the resolved configuration)."""
    a, b = tmp_path / "a", tmp_path / "b"
    common = ["--depth-prior", "exact", "--no-lpips", "--quiet", "--eval-every", "0", "--device", "pocl"]
    assert main(["run", "--method", "dngaussian", "--iterations", "20", "--seed", "4", "--out", str(a), *common]) == 0
    cfg = load_run_config(a / "config.toml")
    assert cfg.seed == 4 and cfg.iterations == (20,) and cfg.sh_degree == 0 and cfg.output.out == str(a)
    assert main(["run", "--config", str(a / "config.toml"), "--out", str(b), "--quiet"]) == 0
    ma, mb = (json.loads((d / "metrics.json").read_text()) for d in (a, b))
    assert ma["mean"] == mb["mean"] and ma["gaussians"] == mb["gaussians"]
    assert load_run_config(b / "config.toml") == dataclasses.replace(cfg, output=dataclasses.replace(cfg.output, out=str(b)))
    capsys.readouterr()


def test_run_takes_the_object_and_refuses_other_positionals(tmp_path):
    with pytest.raises(TypeError, match="expected a RunConfig"):
        reings.run("data/fern")
    with pytest.raises(TypeError, match="unexpected keyword argument 'iters'"):
        reings.run(iters=3)
    r = reings.run(RunConfig(method="3dgs", iterations=(3,), depth_prior="none", output=OutputConfig(lpips=False, eval_every=0)),
                   quiet=True)
    assert [s["stage"] for s in r.metrics["stages"]] == ["init", "3dgs"] and r.metrics["run_config"]["method"] == "3dgs"


def test_profile_records_the_phases_of_every_fit(tmp_path):
    """`--profile`: every fitting stage of metrics.json carries its phases' seconds, the
    view_warp term's among them once it has started (from 2/3 of each fit: iteration 7 of 10)."""
    r = reings.run(method="reings", iterations=10, depth_prior="exact", quiet=True, with_lpips=False, eval_every=0,
                   profile=True, out=str(tmp_path / "p"))
    fits = [st for st in r.metrics["stages"] if st["iterations"]]
    assert [st["stage"] for st in fits] == ["coarse", "fine", "final"]
    for st in fits:
        ph = st["phases"]
        assert {"photo_render", "photo_loss", "photo_backward", "adam", "warp_render", "view_warp",
                "warp_backward"} <= set(ph), (st["stage"], sorted(ph))
        assert all(v >= 0 for v in ph.values()) and st["config"]["loss"]["view_warp_weight"] == 1.0
    off = reings.run(method="reings", iterations=10, depth_prior="exact", quiet=True, with_lpips=False, eval_every=0,
                     out=str(tmp_path / "q"))
    assert all("phases" not in st for st in off.metrics["stages"])


def test_new_inputs_come_from_the_training_views_only(tmp_path, monkeypatch):
    """The leakage guard for this session's inputs: the view_warp baseline's scene depth
    (pipeline.typical_depth) sees the training cameras and the SfM box of the training views; the
    DTU background masks (background.dark_background_mask) see the training images only (or their 2 x 2
    block means: the LLFF family's coarse fit at 1/2, RunConfig.fit_scale)."""
    import reings.background as B
    import reings.pipeline as P
    from reings.data.splits import few_shot_split

    seen_cams, seen_ims = [], []
    td, dm = P.typical_depth, B.dark_background_mask

    def typical_depth(cameras, box):
        seen_cams.append([c.viewmat.tobytes() for c in cameras])
        return td(cameras, box)

    def mask(image, *a, **k):
        seen_ims.append(np.asarray(image).tobytes())
        return dm(image, *a, **k)

    monkeypatch.setattr(P, "typical_depth", typical_depth)
    monkeypatch.setattr(B, "dark_background_mask", mask)
    reings.run(method="reings", iterations=6, depth_prior="exact", quiet=True, with_lpips=False, eval_every=0,
               dtu_background=True, out=str(tmp_path / "g"))
    scene = reings.make_procedural_scene()
    tr, _ = few_shot_split(scene, 3)
    train_cams = [scene.cameras[i].viewmat.tobytes() for i in tr]
    train_ims = {np.asarray(scene.images[i], np.float32).tobytes() for i in tr}
    from reings.train import block_mean

    pooled = {block_mean(scene.images[i], 2).tobytes() for i in tr}
    assert seen_cams and all(c == train_cams for c in seen_cams)
    assert seen_ims and set(seen_ims) <= train_ims | pooled and pooled <= set(seen_ims)


def test_depth_confidence_comes_from_the_training_views_only(tmp_path, monkeypatch):
    """--depth-confidence: the confidence maps that weight the depth loss are the stereo prior's,
    computed from the training views only, and reach every fit that has depth terms; the setting is
    part of the run's settings (a resume with another value is refused) and of each fit's config."""
    import reings.data.depth_prior as DP
    import reings.train as T
    from reings.data.splits import few_shot_split

    seen_ims, got = [], []
    compute = DP.DepthPrior.compute

    def spy_compute(self, scene_train, return_confidence=False):
        seen_ims.extend(np.asarray(im, np.float32).tobytes() for im in scene_train.images)
        return compute(self, scene_train, return_confidence)

    fit = T.fit

    def spy_fit(*a, depth_confidence=None, **k):
        got.append((k.get("depth_targets") is not None, depth_confidence, a[1].loss.depth_confidence))
        return fit(*a, depth_confidence=depth_confidence, **k)

    monkeypatch.setattr(DP.DepthPrior, "compute", spy_compute)
    monkeypatch.setattr("reings.pipeline.fit", spy_fit)
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path / "cache"))
    r = reings.run(method="reings", iterations=4, depth_prior="stereo", depth_confidence=0.5, quiet=True,
                   with_lpips=False, eval_every=0, out=str(tmp_path / "c"))
    scene = reings.make_procedural_scene()
    tr, _ = few_shot_split(scene, 3)
    assert seen_ims and set(seen_ims) <= {np.asarray(scene.images[i], np.float32).tobytes() for i in tr}
    with_depth = [(c, a) for has, c, a in got if has]
    assert with_depth and all(c is not None and len(c) == 3 and a == 0.5 for c, a in with_depth)
    assert all(0 <= float(np.min(m)) and float(np.max(m)) <= 1 for c, _ in with_depth for m in c)
    assert r.metrics["config"]["depth_confidence"] == 0.5
    from reings.pipeline import run_settings

    # the resume guard compares these settings: another strength is another run; 0 adds no key
    # (older run folders stay resumable)
    assert run_settings(RunConfig(depth_confidence=1.0).resolved(), "procedural")["depth_confidence"] == 1.0
    assert "depth_confidence" not in run_settings(RunConfig().resolved(), "procedural")


def test_resume_settings_of_the_stereo_seeds_and_the_shared_soft_depth():
    """The resume guard's settings: the seeds' options are absent where a run behaves as before the
    options existed (3 views, the SfM box), present where the auto rule seeds (2 views, --extent
    stereo) or a fraction is set; the shared soft depth only when on."""
    from reings.config import ReInGSConfig
    from reings.pipeline import run_settings

    s3 = run_settings(RunConfig(views=3).resolved(), "llff")
    assert "stereo_seeds" not in s3 and "stereo_seeds" not in s3["reings_config"]
    assert "stereo_seed_conf" not in s3["reings_config"] and "soft_depth_shared" not in s3
    assert run_settings(RunConfig(views=2).resolved(), "llff")["stereo_seeds"] == "auto"
    assert run_settings(RunConfig(views=3, extent="stereo").resolved(), "llff")["stereo_seeds"] == "auto"
    s = run_settings(RunConfig(views=3, reings=ReInGSConfig(stereo_seeds=0.2, stereo_seed_conf=0.7)).resolved(),
                     "llff")
    assert s["reings_config"]["stereo_seeds"] == 0.2 and s["reings_config"]["stereo_seed_conf"] == 0.7
    assert run_settings(RunConfig(soft_depth_shared=True).resolved(), "llff")["soft_depth_shared"] is True
