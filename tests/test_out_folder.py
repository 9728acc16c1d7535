"""The output folder is never lost and never lies (issue 14, items 1, 3, 6 and 15): a failed
--overwrite leaves the finished run it was meant to replace intact; an unreadable
checkpoints/run.json is refused, not resumed; a successful --overwrite leaves nothing of the old
run behind; an error while reading the inputs writes nothing, so the corrected command runs
without --overwrite. Each case failed before the fix (outputs.prepare_out cleared the folder
first, resumed on an unreadable run.json, and ran before the priors and the scene box)."""
from __future__ import annotations

import json
import os

import pytest

import reings
from reings import outputs, pipeline

KW = dict(method="3dgs", iterations=3, depth_prior="none", quiet=True, with_lpips=False, eval_every=0)


def _finished(out):
    r = reings.run(out=str(out), **KW)
    with open(out / "metrics.json") as f:
        return r, f.read()


def test_failed_overwrite_keeps_the_finished_run(tmp_path, monkeypatch):
    out = tmp_path / "run"
    _, before = _finished(out)
    renders = sorted(os.listdir(out / "renders"))

    def boom(*a, **k):
        raise RuntimeError("scoring failed")

    monkeypatch.setattr(pipeline, "score_test_views", boom)
    with pytest.raises(RuntimeError, match="scoring failed"):
        reings.run(out=str(out), overwrite=True, **dict(KW, iterations=4))
    assert (out / "metrics.json").read_text() == before
    assert sorted(os.listdir(out / "renders")) == renders
    assert not (out / outputs.PREVIOUS).exists()
    with open(out / "checkpoints" / "run.json") as f:
        assert json.load(f)["iterations"] == [3]  # the finished run's settings, not the failed run's


def test_overwrite_leaves_nothing_of_the_old_run(tmp_path):
    out = tmp_path / "run"
    _finished(out)
    (out / "renders" / "stale.png").write_bytes(b"x")
    (out / "depths").mkdir(exist_ok=True)
    (out / "depths" / "stale.png").write_bytes(b"x")
    (out / "checkpoints" / "old_stage.npz").write_bytes(b"x")
    (out / "notes.txt").write_text("the user's own file")
    reings.run(out=str(out), overwrite=True, **dict(KW, iterations=4))
    assert not (out / "renders" / "stale.png").exists() and not (out / "depths" / "stale.png").exists()
    assert not (out / "checkpoints" / "old_stage.npz").exists() and not (out / outputs.PREVIOUS).exists()
    assert (out / "notes.txt").read_text() == "the user's own file"  # not a run output: untouched
    with open(out / "metrics.json") as f:
        assert json.load(f)["config"]["iterations"] == [4]


def test_unreadable_run_json_is_refused(tmp_path):
    out = tmp_path / "run"
    (out / "checkpoints").mkdir(parents=True)
    (out / "checkpoints" / "run.json").write_text("{ not json")
    with pytest.raises(ValueError, match="run.json: unreadable"):
        reings.run(out=str(out), **KW)
    (out / "checkpoints" / "run.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="run.json: unreadable"):
        reings.run(out=str(out), **KW)
    reings.run(out=str(out), overwrite=True, **KW)  # --overwrite starts over
    assert (out / "metrics.json").exists()


def test_input_errors_write_nothing(tmp_path, monkeypatch):
    """An error while computing the scene box (after loading, before training) leaves no
    run.json behind, so the corrected command needs no --overwrite."""
    import reings.data.sfm as S

    out = tmp_path / "run"

    def bad(*a, **k):
        raise ValueError("frusta bounds are bad")

    monkeypatch.setattr(S, "sfm_extent", bad)
    with pytest.raises(ValueError, match="frusta bounds"):
        reings.run(out=str(out), **KW)
    assert not (out / "checkpoints" / "run.json").exists() and not (out / "config.toml").exists()
    monkeypatch.undo()
    reings.run(out=str(out), **KW)
    assert (out / "metrics.json").exists()


def test_killed_overwrite_keeps_the_older_finished_run(tmp_path):
    """A `.previous-run` left by a killed --overwrite holds the last finished run: the next
    --overwrite keeps it (removing the killed run's partial outputs) until it finishes."""
    out = tmp_path / "o"
    (out / outputs.PREVIOUS).mkdir(parents=True)
    (out / outputs.PREVIOUS / "metrics.json").write_text("{}")
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "coarse.npz").write_bytes(b"partial")
    outputs.prepare_out(str(out), {"a": 1}, overwrite=True)
    assert (out / outputs.PREVIOUS / "metrics.json").read_text() == "{}"
    assert not (out / "checkpoints" / "coarse.npz").exists()
    assert outputs.restore_out(str(out)) and (out / "metrics.json").read_text() == "{}"
    assert not (out / outputs.PREVIOUS).exists()
