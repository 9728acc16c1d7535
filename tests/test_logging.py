"""Issue 14 item 23: messages through logging.getLogger("reings"); --quiet silences stage lines,
warnings and the OpenCL compiler's output; no progress bars when stderr is not a terminal; the
library says nothing unless the application configures logging."""
from __future__ import annotations

import logging
import os
import subprocess
import sys

import reings

ARGS = ["run", "--method", "dngaussian", "--iterations", "8", "--depth-prior", "exact", "--no-lpips",
        "--eval-every", "0"]


def _cli(tmp_path, *extra, out="o"):
    env = {**os.environ, "PYTHONWARNINGS": "default"}
    env.pop("REINGS_CL_VERBOSE", None)
    cache = tmp_path / "kcache"  # a fresh pyopencl cache on the first call: the kernels are really compiled
    env["PYOPENCL_CACHE_DIR"] = str(cache)
    env["XDG_CACHE_HOME"] = str(cache)
    return subprocess.run([sys.executable, "-m", "reings.cli", *ARGS, "--out", str(tmp_path / out), *extra],
                          capture_output=True, text=True, env=env, timeout=600)


def test_quiet_cli_prints_only_the_summary_then_stage_lines_without_bars(tmp_path):
    """One fresh kernel cache for both runs (each compile of every kernel costs ~40 s of CI): the
    --quiet run compiles them all and must print nothing on stderr (no stage lines, warnings,
    compiler output or bars; the compiler's output is held back whatever --quiet says:
    program._compiler_output); then a run without --quiet, on the kernels the first compiled, prints
    its stage lines and, its stderr a pipe, no progress bars."""
    r = _cli(tmp_path, "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr  # no stage lines, warnings, compiler output or bars
    assert r.stdout.startswith("dngaussian on procedural")

    r = _cli(tmp_path, out="o2")
    assert r.returncode == 0, r.stderr
    assert "[dngaussian] fit: 8 its" in r.stderr or "[dngaussian]" in r.stderr, r.stderr
    assert "it/s" not in r.stderr and "\r" not in r.stderr  # stderr is a pipe: no progress bars
    assert "warnings generated" not in r.stderr and "CompilerWarning" not in r.stderr


def test_library_run_is_silent_unless_logging_is_configured(tmp_path, capfd, caplog):
    kw = dict(method="dngaussian", iterations=4, depth_prior="exact", with_lpips=False, eval_every=0)
    reings.run(out=str(tmp_path / "a"), **kw)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    with caplog.at_level(logging.INFO, logger="reings"):
        reings.run(out=str(tmp_path / "b"), **kw)
    assert any(r.name == "reings" and "[dngaussian]" in r.getMessage() for r in caplog.records)
