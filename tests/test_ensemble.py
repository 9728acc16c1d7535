"""`--ensemble K`: K members, each the plain run of its seed (sharing the stages before
`--ensemble-from`), scored on the mean image; their files, resume, defaults and refusals."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import reings
from reings import pipeline
from reings.cli import main
from reings.config import RunConfig
from reings.data.splits import few_shot_split
from reings.io.ply import read_ply

KW = dict(method="reings", iterations=8, depth_prior="exact", quiet=True, with_lpips=False, eval_every=0,
          device="pocl")


def _same_model(a, b):
    for f in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def _test_views():
    scene = reings.make_procedural_scene()
    _, te = few_shot_split(scene, 3)
    return scene.subset(te)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An ensemble of 2 (seed 5), the plain runs of its members' seeds, and an ensemble of 3 that
    shares the coarse and fine fits."""
    d = tmp_path_factory.mktemp("ens")
    seed = 5
    cvps_inputs = []  # the means of the model each member's CVPS draws from
    real = pipeline.cvps_select

    def cvps_select(g, *a, **k):
        cvps_inputs.append(g.means.copy())
        return real(g, *a, **k)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pipeline, "cvps_select", cvps_select)
        cvps = reings.run(out=str(d / "cvps"), seed=seed, ensemble=3, ensemble_from="cvps", **KW)
    return {"ens": reings.run(out=str(d / "ens"), seed=seed, ensemble=2, **KW),
            "plain0": reings.run(seed=seed, **KW),
            "plain1": reings.run(seed=pipeline.member_seed(seed, 1), **KW),
            "cvps": cvps, "cvps_inputs": cvps_inputs, "dir": d}


def test_members_are_the_plain_runs_of_their_seeds(runs):
    ens, p0, p1 = runs["ens"], runs["plain0"], runs["plain1"]
    assert pipeline.member_seed(5, 1) == 5 + pipeline.MEMBER_SEED_STRIDE
    assert len(ens.members) == 2 and ens.gaussians is ens.members[0]
    _same_model(ens.members[0], p0.gaussians)  # member 0 is the run without --ensemble, bit for bit
    _same_model(ens.members[1], p1.gaussians)  # member 1 is the run of its own seed
    e = ens.metrics["ensemble"]
    assert e["members"] == 2 and e["from"] == "init" and e["shared_stages"] == []
    assert [p["seed"] for p in e["per_member"]] == [5, 5 + pipeline.MEMBER_SEED_STRIDE]
    assert [p["psnr"] for p in e["per_member"]] == [p0.metrics["mean"]["psnr"], p1.metrics["mean"]["psnr"]]
    assert e["gaussians"] == len(p0.gaussians) + len(p1.gaussians)
    # member 1's fits ran with its seed, and its stages are recorded apart from member 0's
    assert [s["stage"] for s in e["member_stages"]] == [s["stage"] for s in p1.metrics["stages"]]
    assert {s["config"]["seed"] for s in e["member_stages"] if "config" in s} == {5 + pipeline.MEMBER_SEED_STRIDE}
    assert [s["stage"] for s in ens.metrics["stages"]] == [s["stage"] for s in p0.metrics["stages"]]
    # the method clock is both members' stages (the initial points are off it, as for one model)
    on_clock = [s["seconds"] for s in ens.metrics["stages"] + e["member_stages"] if s["stage"] not in ("init", "ehps")]
    assert len(on_clock) == 12 and ens.metrics["seconds"]["method"] == pytest.approx(sum(on_clock))


def test_the_scores_are_the_mean_image_s(runs):
    """The test metrics against an independent float64 computation from the written models."""
    out = runs["dir"] / "ens"
    models = [read_ply(str(out / n)) for n in ("gaussians.ply", "gaussians_member1.ply")]
    test = _test_views()
    psnrs = []
    for cam, ref in zip(test.cameras, test.images):
        imgs = [np.clip(reings.render(g, cam, device="pocl", background=(0.0, 0.0, 0.0)).rgb.astype(np.float64), 0, 1)
                for g in models]
        mse = np.mean(((imgs[0] + imgs[1]) / 2 - np.asarray(ref, np.float64)) ** 2)
        psnrs.append(-10 * np.log10(mse))
    m = runs["ens"].metrics
    assert m["mean"]["psnr"] == pytest.approx(np.mean(psnrs), abs=1e-3)
    # the mean image's MSE is the members' mean MSE minus their spread (docs/method.md §13), so never
    # above it; here the members differ, and the mean image's PSNR is above the members' mean PSNR
    assert m["mean"]["psnr"] > m["ensemble"]["member_psnr_mean"]
    # the renders written are the mean image's (8-bit, rounded)
    import cv2

    name = os.path.splitext(os.path.basename(test.names[0]))[0] + ".png"
    png = cv2.imread(str(out / "renders" / name))[..., ::-1]
    imgs = [np.clip(reings.render(g, test.cameras[0], device="pocl").rgb, 0, 1) for g in models]
    want = np.clip(np.rint((imgs[0] + imgs[1]) / 2 * 255), 0, 255)
    assert np.abs(png.astype(np.int32) - want.astype(np.int32)).max() <= 1


def test_members_share_the_stages_before_ensemble_from(runs):
    r = runs["cvps"]
    e = r.metrics["ensemble"]
    assert e["members"] == 3 and e["shared_stages"] == ["ehps", "coarse", "ivps", "fine"]
    assert [(s["member"], s["stage"]) for s in e["member_stages"]] == [
        (k, n) for k in (1, 2) for n in ("cvps", "final", "final_prune")]
    # every member's CVPS draws from the one shared fine model, the fine fit's checkpoint
    fine = np.load(runs["dir"] / "cvps" / "checkpoints" / "fine.npz")["param/means"]
    assert len(runs["cvps_inputs"]) == 3
    for means in runs["cvps_inputs"]:
        np.testing.assert_array_equal(means, fine)
    # the shared stages equal the plain run's (member 0 is the plain run); the others differ by member
    _same_model(r.members[0], runs["plain0"].gaussians)
    assert not np.array_equal(r.members[1].means[: len(r.members[2])], r.members[2].means[: len(r.members[1])])
    out = runs["dir"] / "cvps"
    ck = sorted(os.listdir(out / "checkpoints"))
    assert ck == ["coarse.npz", "final.npz", "fine.npz", "member1_final.npz", "member2_final.npz", "run.json"]
    assert sorted(n for n in os.listdir(out) if n.endswith(".ply")) == [
        "gaussians.ply", "gaussians_member1.ply", "gaussians_member2.ply"]


def test_an_interrupted_ensemble_resumes_to_the_same_result(tmp_path, monkeypatch, runs):
    """Killed in member 1's fits, the rerun keeps member 0's checkpoints and member 1's done ones and
    ends with the uninterrupted run's numbers and models."""
    out = tmp_path / "cut"
    real, calls = pipeline.fit, []

    def fit(*a, **k):
        calls.append(k.get("checkpoint"))
        if len(calls) == 5:  # member 1's fine fit
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(pipeline, "fit", fit)
    with pytest.raises(KeyboardInterrupt):
        reings.run(out=str(out), seed=5, ensemble=2, **KW)
    assert [os.path.basename(c) for c in calls] == ["coarse.npz", "fine.npz", "final.npz", "member1_coarse.npz",
                                                    "member1_fine.npz"]
    assert not (out / "metrics.json").exists() and not (out / "gaussians_member1.ply").exists()
    monkeypatch.undo()
    res = reings.run(out=str(out), seed=5, ensemble=2, **KW)
    assert res.metrics["mean"] == runs["ens"].metrics["mean"]
    for a, b in zip(res.members, runs["ens"].members):
        _same_model(a, b)
    # --overwrite with one model: the members' files go with the replaced run
    reings.run(out=str(out), seed=5, overwrite=True, **KW)
    assert not (out / "gaussians_member1.ply").exists() and (out / "gaussians.ply").exists()
    assert "ensemble" not in json.loads((out / "metrics.json").read_text())


def test_members_train_on_the_training_views_only(tmp_path, monkeypatch):
    """The leakage guard for the members: every fit of every member gets the training images only (the coarse
    fit their 2 x 2 block means: the LLFF family's fit_scale)."""
    from reings.train import block_mean

    seen = []
    real = pipeline.fit

    def fit(views, *a, **k):
        images = views.images if hasattr(views, "images") else [v[0] for v in views]
        seen.append((k.get("desc"), {np.asarray(im, np.float32).tobytes() for im in images}))
        return real(views, *a, **k)

    monkeypatch.setattr(pipeline, "fit", fit)
    reings.run(seed=1, ensemble=2, **{**KW, "iterations": 3})
    scene = reings.make_procedural_scene()
    tr, _ = few_shot_split(scene, 3)
    train = {np.asarray(scene.images[i], np.float32).tobytes() for i in tr}
    pooled = {block_mean(scene.images[i], 2).tobytes() for i in tr}
    assert len(seen) == 6 and all(s == (pooled if name == "coarse" else train) for name, s in seen)


def test_defaults_settings_and_refusals():
    cfg = RunConfig().resolved()
    assert pipeline.ENSEMBLE_BY_FAMILY == {"llff": 1, "dtu": 2}
    assert pipeline.ensemble_of(cfg, "dtu") == 2 and pipeline.ensemble_of(cfg, "llff") == 1
    assert pipeline.ensemble_of(RunConfig(method="dngaussian").resolved(), "dtu") == 1  # the baselines: one model
    assert pipeline.ensemble_of(RunConfig(ensemble=3).resolved(), "llff") == 3  # given: it wins
    assert pipeline.ensemble_of(RunConfig(method="dngaussian", ensemble=2).resolved(), "llff") == 2
    s = pipeline.run_settings(cfg, "dtu")
    assert (s["ensemble"], s["ensemble_from"]) == (2, "init")
    assert "ensemble" not in pipeline.run_settings(cfg, "llff")  # one model: older folders resume
    assert "ensemble" not in pipeline.run_settings(RunConfig(ensemble=1).resolved(), "dtu")
    with pytest.raises(ValueError, match="ensemble"):
        RunConfig(ensemble=0)
    with pytest.raises(ValueError, match="'coarse' is not a stage of dngaussian"):
        RunConfig(method="dngaussian", ensemble_from="coarse")
    with pytest.raises(ValueError, match="ensemble_from"):
        RunConfig(ensemble_from="final_prune")  # draws nothing: the members would be one model
    assert pipeline.ensemble_split("reings", "cvps") == 4 and pipeline.ensemble_split("dngaussian", "init") == 0
    assert pipeline.run_settings(RunConfig(ensemble=2, ensemble_from="ehps").resolved(), "llff")["ensemble_from"] == "init"
    # the member options without an ensemble are named as ignored; the defaults say nothing
    assert pipeline.option_notes(RunConfig(ensemble_jobs=2, ensemble_from="cvps"), "llff", 3) == [
        "ensemble_from without an ensemble (--ensemble K > 1); ignored",
        "ensemble_jobs without an ensemble (--ensemble K > 1); ignored"]
    assert pipeline.option_notes(RunConfig(ensemble_jobs=2, ensemble_from="cvps"), "dtu", 3) == []
    assert pipeline.option_notes(RunConfig(), "llff", 3) == pipeline.option_notes(RunConfig(), "dtu", 3) == []


def test_cli_refuses_bad_values_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "o"
    for args in (["--ensemble", "0"], ["--ensemble", "x"], ["--ensemble-from", "nowhere"],
                 ["--method", "3dgs", "--ensemble-from", "cvps"]):
        try:
            rc = main(["run", "--out", str(out), "--quiet", *args])
        except SystemExit as e:  # argparse's refusals
            rc = e.code
        assert rc != 0, args
        assert not out.exists(), args
        assert "ensemble" in capsys.readouterr().err, args


def test_render_path_of_an_ensemble_is_the_mean_of_its_members(runs):
    out = runs["dir"] / "ens"
    cams = _test_views().cameras[:2]
    f = reings.render_path(str(out), path="cameras", cameras=cams, device="pocl")
    assert f.meta["members"] == 2 and f.meta["gaussians"] == runs["ens"].metrics["ensemble"]["gaussians"]
    models = [read_ply(str(out / n)) for n in ("gaussians.ply", "gaussians_member1.ply")]
    for frame, cam in zip(f.frames, cams):
        imgs = [np.clip(reings.render(g, cam, device="pocl").rgb.astype(np.float64), 0, 1) for g in models]
        want = np.clip(np.rint((imgs[0] + imgs[1]) / 2 * 255), 0, 255)
        assert np.abs(frame.astype(np.int32) - want.astype(np.int32)).max() <= 1
    one = reings.render_path(runs["ens"].members[0], path="cameras", cameras=cams, device="pocl")
    assert one.meta["members"] == 1 and not all(np.array_equal(a, b) for a, b in zip(one.frames, f.frames))
    with pytest.raises(TypeError, match="item 1"):
        reings.render_path([models[0], "x"], path="cameras", cameras=cams)


def test_export_says_which_member_it_wrote(runs, tmp_path):
    from reings.export import export_run

    paths = export_run(str(runs["dir"] / "ens"), str(tmp_path / "x"))
    head = open(paths[0], "rb").read(4000).decode("ascii", "replace")
    assert "ensemble of 2 models: this file is member 0" in head


def test_resume_and_failed_overwrite_of_shared_stages(tmp_path, monkeypatch):
    """--ensemble-from cvps: killed in member 2's final fit, the rerun reloads the shared fits and
    member 1's, and ends as the uninterrupted run; a failing --overwrite puts every member back."""
    kw = dict(seed=2, ensemble=3, ensemble_from="cvps", **{**KW, "iterations": 5})
    ref = reings.run(**kw)
    out = tmp_path / "r"
    real, calls = pipeline.fit, []

    def fit(*a, **k):
        calls.append(os.path.basename(k.get("checkpoint")))
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(pipeline, "fit", fit)
    with pytest.raises(KeyboardInterrupt):
        reings.run(out=str(out), **kw)
    assert calls == ["coarse.npz", "fine.npz", "final.npz", "member1_final.npz", "member2_final.npz"]
    calls.clear()
    monkeypatch.setattr(pipeline, "fit", lambda *a, **k: (calls.append(os.path.basename(k.get("checkpoint"))),
                                                         real(*a, **k))[1])
    res = reings.run(out=str(out), **kw)
    assert calls == ["coarse.npz", "fine.npz", "final.npz", "member1_final.npz", "member2_final.npz"]
    assert res.metrics["mean"] == ref.metrics["mean"]
    for a, b in zip(res.members, ref.members):
        _same_model(a, b)
    plys = {n: (out / n).read_bytes() for n in ("gaussians.ply", "gaussians_member1.ply", "gaussians_member2.ply")}

    def broken(*a, **k):
        raise RuntimeError("device lost")

    monkeypatch.setattr(pipeline, "fit", broken)
    with pytest.raises(RuntimeError, match="device lost"):
        reings.run(out=str(out), overwrite=True, **kw)
    assert {n: (out / n).read_bytes() for n in plys} == plys  # the replaced run is back, every member
    assert not (out / ".previous-run").exists()


def test_the_dtu_family_defaults_to_two_members_and_eval_tables_them(tmp_path):
    """The DTU recipe family's reings run fits two members unless told; `reings eval` tags the
    ensemble, counts every member's Gaussians, and flags a folder of other member settings."""
    from reings.evaluate import _run_entry, _setting_tag, _settings_differ

    r = reings.run(recipe="dtu", out=str(tmp_path / "dtu"), **{**KW, "iterations": 3})
    e = r.metrics["ensemble"]
    assert e["members"] == 2 and len(r.members) == 2 and r.metrics["config"]["ensemble"] == 2
    assert "ensemble 2" in _setting_tag(r.metrics)
    assert _run_entry(r.metrics, "x")["gaussians"] == e["gaussians"] == sum(len(m) for m in r.members)
    one = reings.run(recipe="dtu", ensemble=1, **{**KW, "iterations": 3})
    assert "ensemble" not in one.metrics and "ensemble" not in _setting_tag(one.metrics)
    path = str(tmp_path / "dtu" / "metrics.json")
    same = RunConfig(recipe="dtu", iterations=(3,), depth_prior="exact")
    assert _settings_differ(path, same, "procedural") == ""
    differ = _settings_differ(path, RunConfig(recipe="dtu", iterations=(3,), depth_prior="exact", ensemble=1),
                              "procedural")
    assert differ.startswith("ensemble 2 != None") and "ensemble_from 'init' != None" in differ


def test_reconstruct_returns_the_members_of_an_ensemble():
    scene = reings.make_procedural_scene()
    views = scene.subset([0, 2, 4])
    # the box from the views' bounds, not SfM: COLMAP's threads may order its matches differently from run to run
    kw = dict(iterations=3, depth_prior="none", extent="frusta", bounds=views.bounds)
    gs = reings.reconstruct(views.images, views.cameras, ensemble=2, **kw)
    assert isinstance(gs, list) and len(gs) == 2 and all(isinstance(g, reings.Gaussians) for g in gs)
    one = reings.reconstruct(views.images, views.cameras, **kw)
    assert isinstance(one, reings.Gaussians)
    _same_model(one, gs[0])


def test_members_in_worker_processes_are_the_same_bits(runs, tmp_path, monkeypatch, caplog):
    """--ensemble-jobs 2: member 1 fits in a worker process while member 0 fits here (this process's
    fit sees member 0's stages only); the models, scores and records are those of the members fitted
    one after another, and the worker's stage lines reach this process's log."""
    import logging

    from reings import ensemble

    assert ensemble.jobs_of(RunConfig(ensemble_jobs=3), 2) == 2  # never more than the members
    assert ensemble.jobs_of(RunConfig(), 3) == 1  # one at a time unless asked
    here, real = [], pipeline.fit

    def fit(*a, **k):
        here.append(os.path.basename(k.get("checkpoint")))
        return real(*a, **k)

    monkeypatch.setattr(pipeline, "fit", fit)
    with caplog.at_level(logging.INFO, logger="reings"):
        par = reings.run(out=str(tmp_path / "par"), seed=5, ensemble=2, ensemble_jobs=2, **KW)
    assert here == ["coarse.npz", "fine.npz", "final.npz"]  # member 1's fits ran elsewhere
    seq = runs["ens"]
    for a, b in zip(par.members, seq.members):
        _same_model(a, b)
    assert par.metrics["mean"] == seq.metrics["mean"]
    pm, sm = par.metrics["ensemble"], seq.metrics["ensemble"]
    assert [p["psnr"] for p in pm["per_member"]] == [p["psnr"] for p in sm["per_member"]]
    assert [s["stage"] for s in pm["member_stages"]] == [s["stage"] for s in sm["member_stages"]]
    assert sorted(os.listdir(tmp_path / "par" / "checkpoints")) == sorted(os.listdir(runs["dir"] / "ens" / "checkpoints"))
    assert any(r.getMessage().startswith("(member 1) [reings] final:") for r in caplog.records)
    assert "ensemble_jobs" not in json.dumps(par.metrics["config"])  # the same results: resumable either way


def test_more_members_than_jobs(runs, tmp_path):
    """K = 3 members, 2 at a time (member 0 here with member 1 in a worker, then member 2 here): the
    members fitted one after another, bit for bit."""
    kw = dict(seed=5, ensemble=3, ensemble_from="cvps", **KW)
    par = reings.run(out=str(tmp_path / "p"), ensemble_jobs=2, **kw)
    for a, b in zip(par.members, runs["cvps"].members):
        _same_model(a, b)
    assert par.metrics["mean"] == runs["cvps"].metrics["mean"]


def test_a_failing_worker_is_a_named_error(tmp_path, monkeypatch):
    """A worker that cannot start (a broken numpy first on its path): a named error with the
    worker's last lines, and nothing left in the temporary folder."""
    import tempfile

    plant = tmp_path / "plant"
    (plant / "numpy").mkdir(parents=True)
    (plant / "numpy" / "__init__.py").write_text("raise ImportError('planted numpy')\n")
    monkeypatch.setenv("PYTHONPATH", str(plant))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    with pytest.raises(RuntimeError, match=r"(?s)ensemble member 1: its worker process failed \(exit code 1\).*planted"):
        reings.run(seed=5, ensemble=2, ensemble_jobs=2, **{**KW, "iterations": 2})
    assert os.listdir(tmp_path / "tmp") == []
