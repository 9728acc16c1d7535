"""The catalogue's "kills at random moments" (issue 14), kept as a table: the cases `kill/*` of
tests/fault_catalogue.py (KILL_ARGS, KILL_MOMENTS). `reings run` (the procedural scene, quick
preset, 24 iterations a stage) in a subprocess is SIGKILLed (or SIGINTed) at moments chosen by what
it has written so far and by seeded random delays; the same command run again finishes with
exactly the uninterrupted run's numbers and Gaussians, and leaves no temporary file (a SIGINT
ends with exit 130 and `reings: interrupted`). scripts/catalogue.py runs the same table."""
from __future__ import annotations

import os

import pytest

import fault_catalogue as fc


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("kills"))
    return fc.Fixtures(os.path.join(root, "fixtures"), fc.case_env()), root


@pytest.mark.slow
@pytest.mark.parametrize("case", fc.cases(("kill",)), ids=lambda c: c.id.split("/")[-1])
def test_killed_run_resumes_to_the_same_result(fixtures, case):
    fx, root = fixtures
    rec = fc.run_case(case, fx, os.path.join(root, "cases"), mode="subprocess", env=fx.env)
    assert rec["outcome"] == "clean", f"{rec['outcome']}: {rec['why']}\n{rec.get('stderr_tail', '')}"
