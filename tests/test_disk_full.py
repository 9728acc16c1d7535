"""Issue 14 item 12: a write the OS refuses (here: the process's file-size limit, RLIMIT_FSIZE,
which fails a write like a full disk does) ends the run with one line naming the file, exit 1, no
traceback, no temporary file left, and nothing already written lost."""
from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

resource = pytest.importorskip("resource")


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


_LIMITED = """
import resource, signal, sys
import reings.io.files as files
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # the write fails with EFBIG instead of killing the process
real = files.atomic_write
def limited(path, binary=False):
    # the limit starts at the first checkpoint (the OpenCL compiler writes its own files before)
    if str(path).endswith(".npz"):
        resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
    return real(path, binary)
files.atomic_write = limited
from reings.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_refused_write_is_one_line_and_loses_nothing(tmp_path):
    out = tmp_path / "run"
    args = ["run", "--method", "dngaussian", "--iterations", "30", "--depth-prior", "exact", "--no-lpips",
            "--eval-every", "0", "--quiet", "--checkpoint-every", "10", "--out", str(out)]
    # 60 kB: the first checkpoint (about 0.2 MB) does not fit
    r = subprocess.run([sys.executable, "-c", _LIMITED.format(limit=60_000), *args], capture_output=True,
                       text=True, timeout=600)
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
