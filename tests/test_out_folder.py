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


def test_outputs_respect_the_umask(tmp_path):
    """Issue 14 item 18: files written through atomic_write (metrics.json, the SVG, run.json,
    results.*, the PLY, checkpoints) were 0600 from mkstemp; they now get 0666 & ~umask."""
    from reings.io.files import atomic_write

    old = os.umask(0o022)
    try:
        with atomic_write(tmp_path / "a.json") as f:
            f.write("{}")
        os.umask(0o077)
        with atomic_write(tmp_path / "b.json") as f:
            f.write("{}")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "a.json").st_mode & 0o777) == 0o644
    assert (os.stat(tmp_path / "b.json").st_mode & 0o777) == 0o600


def test_planted_symlinks_are_not_written_through(tmp_path):
    """Issue 14 item 17: a symlink at OUT/gaussians.ply, or at a checkpoint's old predictable
    temp name, made a run overwrite a file outside --out."""
    import numpy as np

    from reings.io.ply import write_ply
    from reings.train import fit

    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    os.symlink(victim, out / "gaussians.ply")
    scene = reings.make_procedural_scene(n_views=2, width=16, height=12, supersample=1)
    rng = np.random.default_rng(0)
    from reings.train import gaussians_from_points, random_points_in_box

    g = gaussians_from_points(random_points_in_box([-1, 0, 0], [1, 1, 3], 20, rng), None, 0, rng)
    write_ply(out / "gaussians.ply", g)
    assert victim.read_text() == "precious" and not os.path.islink(out / "gaussians.ply")
    ck = out / "fit.npz"
    os.symlink(victim, str(ck) + ".tmp.npz")
    from reings.config import preset
    from reings.train import with_iterations

    fit(scene, with_iterations(preset("3dgs"), 2), init=g, progress=False, checkpoint=str(ck), checkpoint_every=1)
    assert victim.read_text() == "precious" and not os.path.islink(ck)


def test_unreadable_checkpoint_is_named(tmp_path):
    """Issue 14 item 11: a truncated checkpoint gave a bare zipfile.BadZipFile."""
    import numpy as np

    from reings.config import preset
    from reings.train import fit, gaussians_from_points, random_points_in_box, with_iterations

    scene = reings.make_procedural_scene(n_views=2, width=16, height=12, supersample=1)
    rng = np.random.default_rng(0)
    g = gaussians_from_points(random_points_in_box([-1, 0, 0], [1, 1, 3], 20, rng), None, 0, rng)
    ck = tmp_path / "fit.npz"
    fit(scene, with_iterations(preset("3dgs"), 2), init=g, progress=False, checkpoint=str(ck), checkpoint_every=1)
    ck.write_bytes(ck.read_bytes()[:100])
    with pytest.raises(ValueError, match=r"fit.npz: unreadable checkpoint"):
        fit(scene, with_iterations(preset("3dgs"), 4), init=g, progress=False, checkpoint=str(ck))


def test_failed_png_write_is_an_error(tmp_path, monkeypatch):
    """Issue 14 item 8: cv2.imwrite returning False was ignored (exit 0, no renders). PNGs are now
    encoded in memory (cv2.imencode) and written through atomic_write: OpenCV's failure is an error."""
    import cv2

    monkeypatch.setattr(cv2, "imencode", lambda *a, **k: (False, None))
    out = tmp_path / "run"
    with pytest.raises(OSError, match=r"renders/.*\.png: could not write the PNG"):
        reings.run(out=str(out), **KW)
    assert not (out / "metrics.json").exists()
    assert not [n for n in os.listdir(out / "renders") if n.startswith(".tmp-")]  # no temp file left


def test_cli_reports_a_failed_write_in_one_line(tmp_path, monkeypatch, capsys):
    import cv2

    from reings.cli import main

    monkeypatch.setattr(cv2, "imencode", lambda *a, **k: (False, None))
    rc = main(["run", "--method", "3dgs", "--iterations", "3", "--depth-prior", "none", "--no-lpips", "--eval-every", "0",
               "--quiet", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("reings: error:") and "could not write the PNG" in err and "Traceback" not in err


def test_stale_temp_files_are_removed_when_the_folder_is_claimed(tmp_path):
    """Issue 14 item 12 (part): a kill can leave 0-byte `.tmp-*` files that no rerun removed."""
    out = tmp_path / "run"
    for d in ("", "checkpoints", "renders", "depths"):
        (out / d).mkdir(parents=True, exist_ok=True)
        (out / d / ".tmp-abc123.json").write_bytes(b"")
    (out / "keep.tmp-not-ours").write_text("x")
    reings.run(out=str(out), **KW)
    left = [str(p.relative_to(out)) for p in out.rglob(".tmp-*")]
    assert left == [] and (out / "keep.tmp-not-ours").exists()
