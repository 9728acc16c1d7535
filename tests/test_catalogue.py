"""Issue 14's bad-input and fault catalogue kept as test tables (tests/fault_catalogue.py): every
case of the categories bad CLI input (every subcommand), bad data folders (every format), bad API
input, corrupted run folders and symlinks at outputs must come out `clean` (one error line naming
the problem and no traceback; nothing lost; the few valid inputs among them succeed), and the
valid scenes of every format must load to their true cameras (`control`).

The cases run in this process (reings.cli.main, the API) for speed, each in its own sandbox
folder; `scripts/catalogue.py` runs the same table as subprocesses and prints the counts
(docs/catalogue.md). The full-disk and kill tables are in test_disk_full.py and test_kills.py.

FAILED_BEFORE lists the cases that were not clean when the catalogue was first run (each fixed in
the package since); a change that brings one back fails here.
"""
from __future__ import annotations

import os
import shutil

import pytest

import fault_catalogue as fc

TABLE = ("cli", "data", "api", "runfolder", "symlink", "control")

# outcome of each case that was not clean when the catalogue was first run, on commit c7041cd
# (scripts/catalogue.py with PYTHONPATH on an export of that commit; docs/catalogue.md)
FAILED_BEFORE = {
    "cli/run/ehps-gamma-inf": "wrong",
    "cli/run/ehps-beta1-inf": "wrong",
    "cli/run/lpips-model-missing": "wrong",
    "cli/eval/seeds-negative": "unclear",
    "cli/bench/sh-word": "unclear",
    "cli/bench/sh-4": "unclear",
    "cli/bench/repeats-zero": "traceback",
    "cli/bench/n-negative": "unclear",
    "cli/process/out-is-the-photos": "lost",
    "cli/process/out-holds-the-photos": "lost",
    "cli/render/frames-huge": "wrong",
    "cli/render/out-equals-depth-out": "wrong",
    "cli/render/frames-dir-holds-frames": "lost",
    "cli/view/empty-model": "unclear",
    "cli/view/port-negative": "wrong",
    "cli/view/port-huge": "wrong",
    "cli/view/host-bad": "wrong",
    "cli/worker/pocl-threads-negative": "traceback",
    "cli/worker/scheduler-unreachable": "traceback",
    "data/llff/bounds-far-before-near": "unclear",
    "data/llff/bounds-negative": "unclear",
    "data/llff/png-bomb-header": "traceback",
    "data/blender/matrix-singular": "unclear",
    "data/blender/angle-string": "unclear",
    "data/nerfstudio/size-zero": "traceback",
    "data/llff/bounds-far-before-near-extent-frusta": "unclear",
    "api/run/output-int": "unclear",
    "api/render/gaussians-strings": "unclear",
    "api/read_ply/duplicate-property": "unclear",
    "api/other/load-scene-int": "unclear",
    "runfolder/checkpoint-missing-arrays": "traceback",
    "runfolder/checkpoint-wrong-shapes": "wrong",
    "runfolder/checkpoint-rows-differ": "wrong",
    "runfolder/render-camera-huge": "unclear",
    "symlink/out-renders-folder": "lost",
    "symlink/out-depths-folder": "lost",
    "symlink/out-checkpoints-folder": "lost",
    "symlink/previous-run-folder": "lost",
    "disk/run-render-png": "unclear",
    "disk/render-frames": "wrong",
    "disk/render-video": "wrong",
}


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("catalogue"))
    env = fc.case_env(extra={"REINGS_CACHE_DIR": os.path.join(root, "cache")})
    return fc.Fixtures(os.path.join(root, "fixtures"), env), root


def _check(case, sandbox, monkeypatch, mode):
    for mod in case.needs:
        pytest.importorskip(mod)
    fixtures, root = sandbox
    monkeypatch.setenv("REINGS_CACHE_DIR", os.path.join(root, "cache"))
    rec = fc.run_case(case, fixtures, os.path.join(root, "cases"), mode=mode, env=fixtures.env)
    assert rec["outcome"] == "clean", f"{rec['outcome']}: {rec['why']}\n{rec.get('stderr_tail', '')}"
    shutil.rmtree(os.path.join(root, "cases", case.id.replace("/", "__")), ignore_errors=True)


@pytest.mark.slow
@pytest.mark.parametrize("case", fc.cases(TABLE), ids=lambda c: c.id)
def test_case_is_handled_cleanly(case, sandbox, monkeypatch):
    _check(case, sandbox, monkeypatch, "inprocess" if case.inproc else "subprocess")


def test_the_table_covers_every_category_and_subcommand():
    cases = fc.all_cases()
    assert {c.category for c in cases} == set(fc.CATEGORIES)
    assert len([c for c in cases if c.category != "control"]) >= 150
    subcommands = {c.argv[0] for c in cases if c.argv}
    assert subcommands >= {"run", "eval", "bench", "devices", "process", "render", "view", "export", "worker"}
    kinds = {c.id.split("/")[1] for c in cases if c.category == "data"}
    assert kinds == {"llff", "dtu", "colmap", "blender", "nerfstudio"}
    assert set(FAILED_BEFORE) <= {c.id for c in cases}


def test_the_classifier_finds_each_outcome(tmp_path):
    """The runner's verdicts, on made-up results: a traceback, exit 0 where an error was due, an
    error that does not name the problem, a file outside --out, a changed file."""
    ctx = fc.Ctx(str(tmp_path), None)
    c = fc.Case("x", "cli", ("run",), needles=("--views",))
    assert fc.classify_cli(c, ctx, 1, "", "Traceback (most recent call last):\n  ...\nKeyError: 'a'", False)[0] \
        == "traceback"
    assert fc.classify_cli(c, ctx, 0, "", "", False)[0] == "wrong"
    assert fc.classify_cli(c, ctx, 2, "", "reings: error: something is off", False)[0] == "unclear"
    assert fc.classify_cli(c, ctx, 2, "", "reings: error: --views must be >= 2", False)[0] == "clean"
    assert fc.classify_cli(c, ctx, None, "", "", True)[0] == "wrong"
    assert fc.classify_cli(c, ctx, -9, "", "", False)[0] == "traceback"
    before = {"run/metrics.json": ("file", "a"), "victim.txt": ("file", "b")}
    assert fc.data_lost(before, {**before, "out/x": ("file", "c")}, ("out",)) is None
    assert "victim.txt" in fc.data_lost(before, {**before, "victim.txt": ("file", "z")}, ("out",))
    assert "run/metrics.json" in fc.data_lost(before, {"victim.txt": ("file", "b")}, ("out",))
    assert "elsewhere/x" in fc.data_lost(before, {**before, "elsewhere/x": ("file", "c")}, ("out",))
    api = fc.Case("y", "api", call=lambda ctx: None, needles=("m.ply",))
    res = {"raised": "KeyError", "clean_class": False, "message": "'a'", "check": None}
    assert fc.classify_api(api, ctx, res)[0] == "traceback"
    assert fc.classify_api(api, ctx, {**res, "raised": "PlyError", "clean_class": True, "message": "m.ply: bad"})[0] \
        == "clean"
    assert fc.classify_api(api, ctx, {**res, "raised": None})[0] == "wrong"
