"""`reings run` / `reings eval` with bad input: exit status 2, one clear line, nothing written."""
from __future__ import annotations

import json
import os

import pytest

from reings.cli import main


def _fails(argv, capsys, *needles):
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, (rc, err)
    assert err.startswith("reings: error:"), err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, (n, err)
    return err


def _argparse_fails(argv, capsys, *needles):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    for n in needles:
        assert n in err, (n, err)


def test_run_missing_data_folder(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--data", str(tmp_path / "no_such_scene"), "--out", str(out), "--quiet"], capsys,
           "no_such_scene", "not found")
    assert not out.exists()


def test_run_data_is_a_file(tmp_path, capsys):
    f = tmp_path / "scene.txt"
    f.write_text("x")
    out = tmp_path / "out"
    _fails(["run", "--data", str(f), "--out", str(out), "--quiet"], capsys, "not a folder")
    assert not out.exists()


def test_run_zero_views(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--views", "0", "--out", str(out), "--quiet"], capsys, "views", ">= 2")
    assert not out.exists()


def test_run_too_many_views(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--views", "99", "--out", str(out), "--quiet", "--depth-prior", "none"], capsys, "n_views=99")
    assert not (out / "metrics.json").exists() and not (out / "checkpoints").exists()


def test_run_unknown_method(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--method", "nerf", "--out", str(out), "--quiet"], capsys, "unknown method 'nerf'", "dngaussian")
    assert not out.exists()


def test_run_unknown_device(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--device", "tpu9", "--out", str(out), "--quiet"], capsys, "tpu9")
    assert not out.exists()


def test_run_bad_depth_prior(tmp_path, capsys):
    out = tmp_path / "out"
    _fails(["run", "--depth-prior", "onnx:" + str(tmp_path / "missing.onnx"), "--out", str(out), "--quiet"], capsys,
           "missing.onnx")
    assert not out.exists()


def test_run_bad_numbers_are_argparse_errors(tmp_path, capsys):
    _argparse_fails(["run", "--iterations", "0", "--out", str(tmp_path / "o")], capsys, "--iterations", ">= 1")
    _argparse_fails(["run", "--eval-every", "-1", "--out", str(tmp_path / "o")], capsys, "--eval-every")
    _argparse_fails(["run", "--views", "two", "--out", str(tmp_path / "o")], capsys, "--views")
    assert not (tmp_path / "o").exists()


def test_run_refuses_finished_out(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text(json.dumps({"mean": {"psnr": 1.0}}))
    _fails(["run", "--out", str(out), "--quiet"], capsys, "already holds a finished run", "--overwrite")
    assert json.loads((out / "metrics.json").read_text()) == {"mean": {"psnr": 1.0}}  # untouched
    assert sorted(os.listdir(out)) == ["metrics.json"]


def test_eval_bad_input(tmp_path, capsys):
    out = tmp_path / "out"
    root = tmp_path / "root"
    root.mkdir()
    _fails(["eval", "--root", str(tmp_path / "nowhere"), "--out", str(out)], capsys, "nowhere", "not found")
    _fails(["eval", "--root", str(root), "--out", str(out)], capsys, "no", "scene folders found")
    _fails(["eval", "--dataset", "procedural", "--views", "0,3", "--out", str(out)], capsys, "--views", ">= 2")
    _fails(["eval", "--dataset", "procedural", "--views", "a", "--out", str(out)], capsys, "--views", "'a'")
    _fails(["eval", "--dataset", "procedural", "--methods", "reings,nerf", "--out", str(out)], capsys,
           "unknown method 'nerf'")
    _fails(["eval", "--dataset", "procedural", "--device", "tpu9", "--out", str(out)], capsys, "tpu9")
    _fails(["eval", "--table-only", "--out", str(out)], capsys, "not found")
    assert not out.exists()


def test_eval_unknown_scene(tmp_path, capsys):
    root = tmp_path / "root"
    (root / "fern").mkdir(parents=True)
    (root / "fern" / "poses_bounds.npy").write_bytes(b"")  # detected as LLFF by its files
    (root / "masks").mkdir()  # not a scene: skipped
    out = tmp_path / "out"
    _fails(["eval", "--dataset", "llff", "--root", str(root), "--scenes", "fern,trex", "--out", str(out)], capsys,
           "trex", "found: fern")
    assert not out.exists()


# -- --iterations N | A,B,C and --depth-smooth WEIGHT, shared by `run` and `eval`

def _record_run(monkeypatch):
    """Replace reings.pipeline.run (what `reings run` and `reings eval` call) by a stub that records
    the RunConfig it gets; returns the list of recorded configs."""
    from reings import pipeline

    calls = []

    def fake_run(config, **kw):
        calls.append(config)
        return pipeline.RunResult(None, {"mean": {"psnr": 1.0}, "method": config.label, "data": "procedural",
                                         "views": config.views, "device": "pocl",
                                         "seconds": {"method": 0.0, "total": 0.0}, "gaussians": {}})

    monkeypatch.setattr(pipeline, "run", fake_run)
    return calls


def _cli(kind, out, *extra):
    if kind == "run":
        return ["run", "--out", str(out), "--quiet", *extra]
    return ["eval", "--dataset", "procedural", "--views", "2", "--methods", "reings", "--out", str(out),
            "--quiet", *extra]


@pytest.mark.parametrize("kind", ["run", "eval"])
def test_iterations_and_depth_smooth_reach_run(kind, tmp_path, monkeypatch):
    calls = _record_run(monkeypatch)
    assert main(_cli(kind, tmp_path / "a", "--iterations", "100,300,600", "--depth-smooth", "0.05")) == 0
    assert len(calls) == 1
    assert calls[-1].iterations == (100, 300, 600)
    assert calls[-1].stage_iterations() == {"coarse": 100, "fine": 300, "final": 600}
    assert calls[-1].depth_smooth == 0.05
    assert main(_cli(kind, tmp_path / "b", "--iterations", "7")) == 0
    assert calls[-1].iterations == (7,) and calls[-1].stage_iterations() == {"coarse": 7, "fine": 7, "final": 7}
    assert calls[-1].depth_smooth is None  # absent: the preset's weight
    assert main(_cli(kind, tmp_path / "c", "--depth-smooth", "0")) == 0
    assert calls[-1].depth_smooth == 0.0 and calls[-1].iterations is None  # 0 = off, not "absent"
    assert calls[-1].stage_iterations() == {"coarse": 200, "fine": 200, "final": 600}  # the quick preset
    assert len(calls) == 3


@pytest.mark.parametrize("kind", ["run", "eval"])
@pytest.mark.parametrize("bad,why", [("1,2", "A,B,C"), ("0", ">= 1"), ("a,b,c", "expected an integer"),
                                     ("5,-1,3", ">= 1")])
def test_bad_iterations_are_argparse_errors(kind, bad, why, tmp_path, monkeypatch, capsys):
    calls = _record_run(monkeypatch)
    out = tmp_path / "o"
    _argparse_fails(_cli(kind, out, "--iterations", bad), capsys, "argument --iterations", why)
    assert not out.exists() and calls == []


@pytest.mark.parametrize("kind", ["run", "eval"])
@pytest.mark.parametrize("bad,why", [("-1", ">= 0"), ("nan", ">= 0"), ("inf", ">= 0"), ("x", "expected a number")])
def test_bad_depth_smooth_are_argparse_errors(kind, bad, why, tmp_path, monkeypatch, capsys):
    calls = _record_run(monkeypatch)
    out = tmp_path / "o"
    _argparse_fails(_cli(kind, out, "--depth-smooth", bad), capsys, "argument --depth-smooth", why)
    assert not out.exists() and calls == []


@pytest.mark.parametrize("bad", [-1, float("nan"), float("inf"), True])
def test_run_refuses_bad_depth_smooth_before_writing(bad, tmp_path):
    import reings

    out = tmp_path / "out"
    with pytest.raises(ValueError, match="depth_smooth"):
        reings.pipeline.run(out=str(out), depth_smooth=bad, quiet=True)
    assert not out.exists()


def test_issue14_items_2_and_5(tmp_path, capsys):
    """Item 2: `--dataset procedural --data DIR` trained the procedural scene and labelled it with
    DIR's name; item 5: `--out ''` trained and wrote nothing. Both are refused before any work."""
    scene = tmp_path / "fern"
    scene.mkdir()
    _fails(["run", "--dataset", "procedural", "--data", str(scene), "--out", str(tmp_path / "o")], capsys,
           "procedural", "takes no data folder", str(scene))
    assert not (tmp_path / "o").exists()
    _argparse_fails(["run", "--out", ""], capsys, "--out", "empty")
    _argparse_fails(["run", "--out", "   "], capsys, "--out", "empty")
