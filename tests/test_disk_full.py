"""Issue 14 item 12: a write the OS refuses (here: the process's file-size limit, RLIMIT_FSIZE,
which fails a write like a full disk does) ends the run with one line naming the file, exit 1, no
traceback, no temporary file left, and nothing already written lost. The catalogue's "full disk"
category is kept here as a table: the cases `disk/*` of tests/fault_catalogue.py (the limit at a
checkpoint, config.toml, cameras.json, a test render, gaussians.ply, metrics.json, an --overwrite of
a finished run, an export, render frames and a video), each followed by the same command without
the limit, which must finish."""
from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

resource = pytest.importorskip("resource")

import fault_catalogue as fc  # noqa: E402


def test_atomic_write_names_the_file_and_leaves_nothing(tmp_path):
    from reings.io.files import atomic_write

    target = tmp_path / "metrics.json"
    target.write_text("old")
    with pytest.raises(OSError) as ei:
        with atomic_write(target) as f:
            f.write("new")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert ei.value.errno == errno.ENOSPC and str(target) in str(ei.value)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["metrics.json"]


def test_a_refused_write_is_one_line_and_loses_nothing(tmp_path):
    out = tmp_path / "run"
    args = ["run", "--method", "dngaussian", "--iterations", "30", "--depth-prior", "exact", "--no-lpips",
            "--eval-every", "0", "--quiet", "--checkpoint-every", "10", "--checkpoint-seconds", "0", "--out", str(out)]
    # 60 kB from the first checkpoint on (about 0.2 MB): it does not fit
    env = {**os.environ, "REINGS_TEST_FSIZE_AT": "*/checkpoints/*.npz", "REINGS_TEST_FSIZE_LIMIT": "60000"}
    r = subprocess.run([sys.executable, "-c", fc.FSIZE_WRAPPER, *args], capture_output=True, text=True, timeout=600,
                       env=env)
    assert r.returncode == 1, (r.returncode, r.stderr[-2000:])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("reings: error: writing "), r.stderr[-2000:]
    assert "checkpoints" in lines[0] and "Traceback" not in r.stderr
    left = [os.path.join(d, n) for d, _, ns in os.walk(out) for n in ns if n.startswith(".tmp-")]
    assert left == []
    assert (out / "config.toml").is_file() and (out / "checkpoints" / "run.json").is_file()
    # the same command without the limit resumes the folder and finishes
    r2 = subprocess.run([sys.executable, "-m", "reings.cli", *args], capture_output=True, text=True, timeout=600)
    assert r2.returncode == 0, r2.stderr[-2000:]
    assert (out / "metrics.json").is_file()


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("disk"))
    env = fc.case_env(extra={"REINGS_CACHE_DIR": os.path.join(root, "cache")})
    return fc.Fixtures(os.path.join(root, "fixtures"), env), root


@pytest.mark.slow
@pytest.mark.parametrize("case", fc.cases(("disk",)), ids=lambda c: c.id.split("/")[-1])
def test_a_full_disk_at_each_write(fixtures, case):
    fx, root = fixtures
    rec = fc.run_case(case, fx, os.path.join(root, "cases"), mode="subprocess", env=fx.env)
    assert rec["outcome"] == "clean", f"{rec['outcome']}: {rec['why']}\n{rec.get('stderr_tail', '')}"
