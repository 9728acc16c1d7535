"""The catalogue's "kills at random moments" (issue 14), kept as a table: `reings run` in a
subprocess is SIGKILLed (or SIGINTed) at moments chosen by what it has written so far and by
seeded random delays; the same command run again finishes with exactly the uninterrupted run's
numbers and Gaussians, and leaves no temporary file."""
from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

ARGS = ["run", "--method", "reings", "--iterations", "24", "--depth-prior", "exact", "--no-lpips",
        "--eval-every", "6", "--checkpoint-every", "4", "--seed", "2", "--quiet"]


def _cmd(out):
    return [sys.executable, "-m", "reings.cli", *ARGS, "--out", str(out)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "run"
    r = subprocess.run(_cmd(out), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return out


def _wait_for(out, pattern, proc, timeout=300):
    t = time.time()
    while not glob.glob(os.path.join(str(out), pattern)):
        assert proc.poll() is None, "the run ended before the kill point"
        assert time.time() - t < timeout
        time.sleep(0.01)


# (what must exist before the signal, extra delay in s, signal)
MOMENTS = [("config.toml", 0.0, signal.SIGKILL),                 # right after the folder is claimed
           ("checkpoints/fine.npz", 0.0, signal.SIGINT),         # Ctrl-C in the fine fit
           ("checkpoints/final.npz", "random", signal.SIGKILL),  # somewhere in the final fit
           ("renders/*.png", 0.0, signal.SIGKILL)]               # while the test renders are written


@pytest.mark.slow
@pytest.mark.parametrize("moment", range(len(MOMENTS)), ids=lambda i: MOMENTS[i][0].split("/")[-1])
def test_killed_run_resumes_to_the_same_result(reference, tmp_path, moment):
    pattern, delay, sig = MOMENTS[moment]
    if delay == "random":
        delay = float(np.random.default_rng(moment).uniform(0.0, 1.5))
    out = tmp_path / "run"
    p = subprocess.Popen(_cmd(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(out, pattern, p)
        time.sleep(delay)
        if p.poll() is None:
            p.send_signal(sig)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    if sig == signal.SIGINT and p.returncode != 0:
        assert p.returncode == 130 and err.strip().endswith("reings: interrupted"), err[-2000:]
    r = subprocess.run(_cmd(out), capture_output=True, text=True, timeout=600)
    if r.returncode == 2 and "already holds a finished run" in r.stderr:
        pass  # the kill came after metrics.json: the run was complete
    else:
        assert r.returncode == 0, r.stderr[-2000:]
    want = json.loads((reference / "metrics.json").read_text())
    got = json.loads((out / "metrics.json").read_text())
    assert got["mean"] == want["mean"] and got["gaussians"] == want["gaussians"]
    assert (out / "gaussians.ply").read_bytes() == (reference / "gaussians.ply").read_bytes()
    assert sorted(os.listdir(out / "renders")) == sorted(os.listdir(reference / "renders"))
    left = [os.path.join(d, n) for d, _, ns in os.walk(out) for n in ns if n.startswith(".tmp-")]
    assert left == []
