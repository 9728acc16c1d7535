"""`reings eval`: the results table from run folders (--table-only), locks, and a tiny real eval."""
from __future__ import annotations

import json
import os
import pathlib

import numpy as np
import pytest

from reings import evaluate
from reings.cli import main


def _fake_run(out, dataset, method, views, scene, psnr, ssim, lpips, avge, seconds=10.0, preset="quick",
              iterations=None, gaussians=1000, seed=0):
    d = pathlib.Path(evaluate.run_dir(str(out), dataset, method, views, scene, seed))
    d.mkdir(parents=True)
    base = method.split("-")[0]
    its = iterations or {"reings": [200, 200, 600]}.get(base, [600])
    m = {"method": method, "base_method": base, "scene": scene, "dataset": dataset, "views": views,
         "preset": preset, "device": "cuda:0", "device_name": "FakeGPU", "seed": seed, "depth_prior": "stereo",
         "mean": {"psnr": psnr, "ssim": ssim, "lpips": lpips, "avge": avge},
         "seconds": {"method": seconds, "total": seconds + 5},
         "stages": [{"stage": "final", "gaussians": gaussians}],
         "config": {"preset": preset, "iterations": its}}
    (d / "metrics.json").write_text(json.dumps(m))
    return d


def test_table_only_builds_the_paper_layout(tmp_path, capsys):
    out = tmp_path / "res"
    _fake_run(out, "llff", "reings", 3, "fern", 20.0, 0.70, 0.20, 0.10, seconds=100, gaussians=1000)
    _fake_run(out, "llff", "reings", 3, "flower", 22.0, 0.80, 0.10, 0.08, seconds=300, gaussians=3000)
    _fake_run(out, "llff", "reings", 2, "fern", 18.0, 0.60, 0.30, 0.15)
    _fake_run(out, "llff", "dngaussian", 3, "fern", 17.0, 0.50, 0.40, 0.20)
    _fake_run(out, "llff", "reings-no-ehps", 3, "fern", 19.0, 0.65, 0.25, 0.12)
    _fake_run(out, "dtu", "reings", 3, "scan24", 21.0, 0.83, 0.17, 0.08)
    unfinished = out / "llff" / "dngaussian" / "3views" / "flower"
    (unfinished / "checkpoints").mkdir(parents=True)
    (out / "llff" / "3dgs" / "3views" / "fern").mkdir(parents=True)  # empty folder: ignored

    assert main(["eval", "--table-only", "--out", str(out)]) == 0
    assert "6 finished run(s)" in capsys.readouterr().out
    res = json.loads((out / "results.json").read_text())
    llff = res["datasets"]["llff"]
    assert llff["views"] == [2, 3] and llff["scenes"] == ["fern", "flower"]
    assert list(llff["methods"]) == ["reings", "reings-no-ehps", "dngaussian"]  # reings family first
    r3 = llff["methods"]["reings"]["mean"]["3"]
    assert r3["psnr"] == pytest.approx(21.0) and r3["ssim"] == pytest.approx(0.75)
    assert r3["lpips"] == pytest.approx(0.15) and r3["avge"] == pytest.approx(0.09)
    assert r3["seconds"] == pytest.approx(200) and r3["gaussians"] == pytest.approx(2000)
    assert r3["n_scenes"] == 2 and r3["complete"]
    r2 = llff["methods"]["reings"]["mean"]["2"]
    assert r2["n_scenes"] == 1 and not r2["complete"]
    assert llff["methods"]["reings"]["scenes"]["flower"]["3"]["psnr"] == 22.0
    assert llff["methods"]["reings"]["scenes"]["flower"]["3"]["run"] == os.path.join("llff", "reings", "3views", "flower")
    assert res["datasets"]["dtu"]["methods"]["reings"]["mean"]["3"]["psnr"] == 21.0
    status = {r["path"]: r["status"] for r in res["runs"]}
    assert status[os.path.join("llff", "dngaussian", "3views", "flower")] == "unfinished"
    assert sum(s == "done" for s in status.values()) == 6

    md = (out / "results.md").read_text()
    assert md.index("## DTU") < md.index("## LLFF")  # datasets in name order
    lines = md[md.index("## LLFF"):].splitlines()
    header = next(ln for ln in lines if ln.startswith("| Method | PSNR"))
    assert header.count("PSNR") == 2 and "AVGE↓ 3v" in header  # metric x views columns, 2 and 3 views
    row = next(ln for ln in lines if ln.startswith("| reings (ours)"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1:3] == ["18.00 (1/2)", "21.00"] and cells[3:5] == ["0.600 (1/2)", "0.750"]
    # the paper's numbers right under ours, cited
    i = lines.index(row)
    assert lines[i + 1].startswith("| ReInGS (paper), paper Table 2 | 19.39 | 20.88 | 0.599 | 0.687")
    dng = next(ln for ln in lines if ln.startswith("| DNGaussian ✗SD (paper), paper Table 2"))
    assert "18.87" in dng and "16.47" in dng
    abl = next(ln for ln in lines if ln.startswith("| IVPS+CVPS (paper), paper Table 4 row 5"))
    assert "19.66" in abl
    assert any(ln.startswith("| 3DGS ✗SD (paper)") for ln in lines)  # paper rows of methods not run, too
    dtu_part = md[md.index("## DTU"):md.index("## LLFF")]
    assert "| ReInGS (paper), paper Table 3 | 21.30 |" in dtu_part
    assert "| fern / reings | 18.00 | 20.00 |" in md  # per-scene table
    assert "`" + os.path.join("llff", "dngaussian", "3views", "flower") + "`" in md


def test_table_separates_settings(tmp_path):
    out = tmp_path / "res"
    _fake_run(out, "llff", "reings", 3, "fern", 20.0, 0.7, 0.2, 0.1)
    d = _fake_run(out / "paper_runs", "llff", "reings", 3, "fern", 21.0, 0.7, 0.2, 0.1, preset="paper",
                  iterations=[6000, 6000, 6000])
    assert d.is_dir()
    res = evaluate.build_table(str(out))
    names = list(res["datasets"]["llff"]["methods"])
    assert names == ["reings [paper]", "reings [quick]"]


def test_table_separates_ssim_weights(tmp_path):
    """Runs that differ only in --lambda-dssim (metrics.json config "lambda_dssim", absent at the recipe's)
    get rows of their own: not one cell, where one run's seed would replace the other's."""
    out = tmp_path / "res"
    _fake_run(out, "llff", "reings", 3, "fern", 20.0, 0.7, 0.2, 0.1)
    d = _fake_run(out / "ssim", "llff", "reings", 3, "fern", 19.0, 0.7, 0.2, 0.1)
    m = json.loads((d / "metrics.json").read_text())
    m["config"]["lambda_dssim"] = 0.3
    (d / "metrics.json").write_text(json.dumps(m))
    methods = evaluate.build_table(str(out))["datasets"]["llff"]["methods"]
    assert {k: v["mean"][3]["psnr"] for k, v in methods.items()} == {"reings [quick]": 20.0,
                                                                      "reings [quick, ssim 0.3]": 19.0}
    for key, value, tag in (("lambda_dssim", [0.2, 0.2, 0.4], "ssim 0.2/0.2/0.4"),
                            ("grad_threshold_scale", 1.2, "grad x1.2"), ("soft_depth_shared", True, "soft shared")):
        m["config"].pop("lambda_dssim", None)
        m["config"][key] = value
        (d / "metrics.json").write_text(json.dumps(m))
        methods = evaluate.build_table(str(out))["datasets"]["llff"]["methods"]
        assert f"reings [quick, {tag}]" in methods, (key, list(methods))
        del m["config"][key]


def test_run_lock_is_exclusive(tmp_path):
    a, b = evaluate.RunLock(str(tmp_path / "r")), evaluate.RunLock(str(tmp_path / "r"))
    assert a.acquire()
    assert not b.acquire()  # flock locks are per open file description: a second one fails
    a.release()
    assert b.acquire()
    b.release()


def test_eval_procedural_end_to_end_and_skip(tmp_path, capsys):
    out = tmp_path / "ev"
    argv = ["eval", "--dataset", "procedural", "--views", "2", "--methods", "dngaussian,reings",
            "--no-ivps", "--no-cvps", "--iterations", "5", "--depth-prior", "exact", "--no-lpips", "--quiet",
            "--eval-every", "0", "--out", str(out)]
    assert main(argv) == 0
    res = json.loads((out / "results.json").read_text())
    methods = res["datasets"]["procedural"]["methods"]
    assert set(methods) == {"dngaussian", "reings-no-ivps-no-cvps"}
    assert (out / "procedural" / "reings-no-ivps-no-cvps" / "2views" / "procedural" / "metrics.json").is_file()
    first = (out / "procedural" / "dngaussian" / "2views" / "procedural" / "metrics.json").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv[:-1] + [str(out)]) == 0  # rerun: both runs are skipped
    assert (out / "procedural" / "dngaussian" / "2views" / "procedural" / "metrics.json").stat().st_mtime_ns == first
    assert "results.md" in capsys.readouterr().out


# -- --final-prune / --prune-curve / --depth-smooth in `reings eval`

def test_eval_passes_final_prune_and_prune_curve(tmp_path, monkeypatch):
    from reings import pipeline

    calls = []

    def fake_run(config, **kw):
        calls.append(config)
        return pipeline.RunResult(None, {"mean": {"psnr": 1.0}}, [])

    monkeypatch.setattr(pipeline, "run", fake_run)
    base = ["eval", "--dataset", "procedural", "--views", "2", "--methods", "reings", "--quiet"]
    assert main(base + ["--final-prune", "0.3", "--prune-curve", "--out", str(tmp_path / "a")]) == 0
    assert len(calls) == 1
    assert calls[0].reings.final_prune == 0.3 and calls[0].output.prune_curve is True
    assert main(base + ["--out", str(tmp_path / "b")]) == 0
    assert calls[1].reings.final_prune == 0.1 and calls[1].output.prune_curve is False  # the default
    assert calls[1].depth_smooth is None


def test_setting_tag_names_smoothness_and_prune():
    m = {"method": "reings", "base_method": "reings", "preset": "quick", "seed": 0, "depth_prior": "stereo",
         "config": {"preset": "quick", "iterations": [200, 200, 600], "depth_smooth": 0.0,
                    "reings_config": {"final_prune": 0.5}}}
    tag = evaluate._setting_tag(m)
    assert "smooth 0" in tag and "prune 0.5" in tag, tag
    plain = {**m, "config": {"preset": "quick", "iterations": [200, 200, 600], "reings_config": {"final_prune": 0.1}}}
    tag = evaluate._setting_tag(plain)  # the default prune (0.1) is no distinction
    assert "smooth" not in tag and "prune" not in tag, tag
    assert tag == "quick"
    off = {**m, "config": {"preset": "quick", "iterations": [200, 200, 600], "reings_config": {"final_prune": 0.0}}}
    assert "prune 0" in evaluate._setting_tag(off)
    dng = {**off, "method": "dngaussian", "base_method": "dngaussian"}
    assert "prune" not in evaluate._setting_tag(dng)


@pytest.mark.parametrize("method,stages", [("dngaussian", ["dngaussian"]), ("reings", ["coarse", "fine", "final"])])
def test_depth_smooth_overrides_every_stage(method, stages, tmp_path, device):
    from reings import pipeline

    kw = dict(method=method, iterations=4 if method == "dngaussian" else 2, depth_prior="exact", quiet=True,
              with_lpips=False, eval_every=0, device=device)
    pipeline.run(out=str(tmp_path / "r"), depth_smooth=0.25, **kw)
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    fits = [s for s in m["stages"] if "config" in s]  # the stages that do not fit (ehps, ivps, ...) have none
    assert [s["stage"] for s in fits] == stages
    assert [s["config"]["loss"]["depth_smooth_weight"] for s in fits] == [0.25] * len(stages)
    assert m["config"]["depth_smooth"] == 0.25
    assert "smooth 0.25" in evaluate._setting_tag(m)
    pipeline.run(out=str(tmp_path / "p"), **kw)  # depth_smooth=None: the preset's (DNGaussian LLFF) 0.1
    m = json.loads((tmp_path / "p" / "metrics.json").read_text())
    assert [s["config"]["loss"]["depth_smooth_weight"] for s in m["stages"] if "config" in s] == [0.1] * len(stages)
    assert "depth_smooth" not in m["config"]
    if method == "dngaussian":  # the stereo prior's default is no smoothness
        pipeline.run(out=str(tmp_path / "s"), **{**kw, "depth_prior": "stereo"})
        m = json.loads((tmp_path / "s" / "metrics.json").read_text())
        assert [s["config"]["loss"]["depth_smooth_weight"] for s in m["stages"] if "config" in s] == [0.0]


# -- seeds: one run folder per seed, the table's mean and min-max over seeds

def test_table_mean_and_spread_over_seeds(tmp_path, capsys):
    out = tmp_path / "res"
    for seed, psnr in ((0, 20.0), (1, 21.0), (2, 22.0)):
        _fake_run(out, "llff", "reings", 3, "fern", psnr, 0.7, 0.2, 0.1, seed=seed, seconds=10.0 * (seed + 1))
    for seed, psnr in ((0, 24.0), (1, 26.0)):
        _fake_run(out, "llff", "reings", 3, "flower", psnr, 0.8, 0.1, 0.1, seed=seed)
    assert (out / "llff" / "reings" / "3views" / "fern_seed2" / "metrics.json").is_file()
    assert main(["eval", "--table-only", "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    mth = res["datasets"]["llff"]["methods"]
    assert list(mth) == ["reings"]  # seeds are replicates, not settings
    cell = mth["reings"]["mean"]["3"]
    assert cell["psnr"] == pytest.approx((21.0 + 25.0) / 2)  # mean over scenes of each scene's mean over seeds
    assert cell["seeds"] == [0, 1, 2] and cell["n_scenes"] == 2 and cell["complete"]
    per_seed = [(20 + 24) / 2, (21 + 26) / 2, 22.0]  # per seed: the mean over the scenes it covers
    assert cell["spread"]["psnr"] == pytest.approx([min(per_seed), max(per_seed)])
    assert cell["std"]["psnr"] == pytest.approx(float(np.std(per_seed, ddof=1)))
    assert cell["spread"]["ssim"] == pytest.approx([0.7, 0.75])  # seed 2 covers fern (0.7) only
    fern = mth["reings"]["scenes"]["fern"]["3"]
    assert fern["psnr"] == pytest.approx(21.0) and fern["spread"]["psnr"] == [20.0, 22.0] and fern["seeds"] == [0, 1, 2]
    assert fern["seconds"] == pytest.approx(20.0) and fern["runs"]["2"] == os.path.join("llff", "reings", "3views", "fern_seed2")
    md = (out / "results.md").read_text()
    assert "| reings (ours) | 23.00 [22.00–23.50] |" in md
    assert "| fern / reings | 21.00 [20.00–22.00] |" in md and "| flower / reings | 25.00 [24.00–26.00] |" in md
    assert "Seeds 0, 1, 2:" in md
    capsys.readouterr()


def test_eval_seeds_one_run_each(tmp_path, monkeypatch, capsys):
    from reings import pipeline

    calls = []

    def fake_run(config, **kw):
        calls.append(config)
        return pipeline.RunResult(None, {"mean": {"psnr": 1.0}}, [])

    monkeypatch.setattr(pipeline, "run", fake_run)
    out = tmp_path / "ev"
    argv = ["eval", "--dataset", "procedural", "--views", "2,3", "--methods", "reings,dngaussian", "--seeds", "0,2",
            "--no-cvps", "--cvps-fraction", "0.5", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    got = [(c.views, c.label, c.seed, os.path.relpath(c.output.out, out)) for c in calls]
    d = os.path.join
    assert got == [(2, "reings-no-cvps", 0, d("procedural", "reings-no-cvps", "2views", "procedural")),
                   (2, "reings-no-cvps", 2, d("procedural", "reings-no-cvps", "2views", "procedural_seed2")),
                   (2, "dngaussian", 0, d("procedural", "dngaussian", "2views", "procedural")),
                   (2, "dngaussian", 2, d("procedural", "dngaussian", "2views", "procedural_seed2")),
                   (3, "reings-no-cvps", 0, d("procedural", "reings-no-cvps", "3views", "procedural")),
                   (3, "reings-no-cvps", 2, d("procedural", "reings-no-cvps", "3views", "procedural_seed2")),
                   (3, "dngaussian", 0, d("procedural", "dngaussian", "3views", "procedural")),
                   (3, "dngaussian", 2, d("procedural", "dngaussian", "3views", "procedural_seed2"))]
    assert all(c.reings.cvps_fraction == 0.5 and c.dataset is None and c.data is None for c in calls)  # built-in scene
    calls.clear()
    assert main(["eval", "--dataset", "procedural", "--views", "2", "--seed", "5", "--quiet", "--out", str(out)]) == 0
    assert [(c.label, c.seed, os.path.basename(c.output.out)) for c in calls] == [("reings", 5, "procedural_seed5")]
    assert main(["eval", "--dataset", "procedural", "--seeds", "0,x", "--out", str(out)]) == 2
    assert "--seeds" in capsys.readouterr().err


def test_eval_warns_about_a_finished_run_of_other_settings(tmp_path, monkeypatch, capsys):
    from reings import pipeline

    monkeypatch.setattr(pipeline, "run", lambda *a, **k: pytest.fail("a finished run is never redone"))
    out = tmp_path / "ev"
    d = out / "procedural" / "reings" / "2views" / "procedural"
    d.mkdir(parents=True)
    (d / "metrics.json").write_text(json.dumps({"mean": {"psnr": 1.0}, "config": {"preset": "paper", "seed": 0}}))
    assert main(["eval", "--dataset", "procedural", "--views", "2", "--quiet", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "finished earlier with other settings (preset 'paper' != 'quick'" in err, err
