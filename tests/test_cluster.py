"""`reings eval --cluster` (issue 16): a local Dask cluster of 2 worker processes on PoCL runs a
grid of 4 quick procedural runs; one worker is killed (SIGKILL) during a task; the grid completes,
and its table equals a serial `reings eval` of the same grid."""
from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("distributed")

GRID = ["--dataset", "procedural", "--views", "2,3", "--seeds", "0,1", "--methods", "dngaussian",
        "--iterations", "24", "--checkpoint-every", "4", "--checkpoint-seconds", "0", "--depth-prior", "exact",
        "--no-lpips", "--eval-every", "0", "--quiet"]


def _means(out) -> dict:
    return {os.path.relpath(p, out): json.load(open(p))["mean"]
            for p in sorted(glob.glob(os.path.join(out, "procedural", "*", "*", "*", "metrics.json")))}


def _quality_table(out) -> str:
    """results.md without its generation line and the seconds/Gaussians table."""
    text = open(os.path.join(out, "results.md")).read()
    keep = [ln for ln in text.splitlines() if not ln.startswith("Generated") and "seconds" not in ln]
    return "\n".join(ln for ln in keep if "pthread" not in ln)


@pytest.mark.slow
def test_killed_worker_and_the_serial_table(tmp_path, monkeypatch):
    from reings.cli import build_parser, config_from_args
    from reings.cluster import start_local, run_grid
    from reings.evaluate import plan, write_tables

    monkeypatch.setattr(os, "cpu_count", lambda: 2)  # one PoCL thread per worker, on any machine
    out = tmp_path / "grid"
    args = build_parser().parse_args(["eval", *GRID, "--out", str(out)])
    jobs, expected = plan(args, config_from_args(args))
    assert len(jobs) == 4
    client = start_local(2, "pocl")
    try:
        result, lines = {}, []
        t = threading.Thread(target=lambda: result.setdefault("failed", run_grid(client, jobs, quiet=True,
                                                                                   say=lines.append)))
        t.start()
        deadline = time.time() + 300
        # both workers' first runs have a checkpoint: whichever worker dies, its run can resume
        while len({os.path.dirname(os.path.dirname(p)) for p in
                   glob.glob(str(out / "**" / "checkpoints" / "*.npz"), recursive=True)}) < 2:
            assert time.time() < deadline, "the two first runs wrote no checkpoint"
            time.sleep(0.2)
        pids = client.run(os.getpid)  # {worker address: pid}
        victim = sorted(pids.values())[0]
        os.kill(victim, signal.SIGKILL)  # a worker dies during its task
        t.join(timeout=600)
        assert not t.is_alive()
        assert result["failed"] == []
        assert victim not in client.run(os.getpid).values()  # the nanny started a new process
        # workers (restarted ones too) run without Dask's malloc trim threshold (cluster._worker_environ)
        envs = client.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OMP_NUM_THREADS")))
        assert all(v == (os.environ.get("MALLOC_TRIM_THRESHOLD_"), "1") for v in envs.values()), envs
        # the killed worker's run was retried and went on from its own checkpoints
        assert any(": resumed" in ln for ln in lines), lines
    finally:
        client.close()
        client.cluster.close()
    write_tables(str(out), expected)

    serial = tmp_path / "serial"
    env = {**os.environ, "POCL_MAX_PTHREAD_COUNT": "1"}
    r = subprocess.run([sys.executable, "-m", "reings.cli", "eval", *GRID, "--out", str(serial)],
                       capture_output=True, text=True, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    assert _means(out) == _means(serial) and len(_means(out)) == 4
    assert _quality_table(out) == _quality_table(serial)


def test_cluster_errors(tmp_path, capsys):
    from reings.cli import main

    assert main(["eval", *GRID, "--out", str(tmp_path / "o"), "--cluster", "local:x"]) == 2
    assert "expected local:N" in capsys.readouterr().err
    assert main(["eval", *GRID, "--out", str(tmp_path / "o"), "--cluster", "nowhere"]) == 2
    assert "scheduler address" in capsys.readouterr().err
    assert main(["eval", *GRID, "--out", str(tmp_path / "o"), "--runs-per-gpu", "4"]) == 2
    assert "only with --cluster local" in capsys.readouterr().err
    assert main(["eval", *GRID, "--out", str(tmp_path / "o"), "--cluster", "local:1", "--runs-per-gpu", "0"]) == 2
    assert "needs K >= 1" in capsys.readouterr().err
    assert main(["worker", "--scheduler", "tcp://127.0.0.1:1", "--runs", "0"]) == 2
    assert "--runs 0" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_worker_specs_share_each_gpu(monkeypatch):
    """--runs-per-gpu K: K workers per GPU (GPU=1 each), then PoCL workers on the spare cores; the
    K workers of a GPU get 1/K of the sync-free binning's memory budget each."""
    from reings.backends.opencl import device
    from reings.cluster import ClusterError, worker_specs

    monkeypatch.setattr(device, "list_devices", lambda: [{"nv_ptx": True}, {"nv_ptx": True}, {"nv_ptx": False}])
    monkeypatch.setattr(os, "cpu_count", lambda: 16)
    monkeypatch.delenv("REINGS_BIN_BUDGET", raising=False)
    specs = worker_specs(7, "cuda", runs_per_gpu=3)
    assert [s["device"] for s in specs] == ["cuda:0"] * 3 + ["cuda:1"] * 3 + ["pocl"]
    assert all(s["resources"] == {"RUN": 1, "GPU": 1} for s in specs[:6])
    assert specs[6]["resources"] == {"RUN": 1} and specs[6]["env"]["POCL_MAX_PTHREAD_COUNT"] == "10"
    assert [s["device"] for s in worker_specs(None, "cuda", runs_per_gpu=2)] == ["cuda:0", "cuda:0", "cuda:1", "cuda:1"]
    assert [s["device"] for s in worker_specs(2, "cuda")] == ["cuda:0", "cuda:1"]
    # K runs sharing a GPU share the sync-free binning's memory budget (docs/perf_notes.md §8)
    assert all(float(s["env"]["REINGS_BIN_BUDGET"]) == 0.25 / 3 for s in specs[:6])
    assert "REINGS_BIN_BUDGET" not in worker_specs(2, "cuda")[0]["env"]
    monkeypatch.setenv("REINGS_BIN_BUDGET", "0.1")
    assert "REINGS_BIN_BUDGET" not in worker_specs(2, "cuda", runs_per_gpu=2)[0]["env"]
    with pytest.raises(ClusterError, match="--runs-per-gpu"):
        worker_specs(2, "cuda", runs_per_gpu=0)


def test_worker_environ_drops_the_malloc_trim_threshold(monkeypatch):
    """Dask's nannies set MALLOC_TRIM_THRESHOLD_=65536, which makes large numpy temporaries 3-17x
    slower (docs/results.md §15); reings' nannies are made without it, keeping the thread limits."""
    pytest.importorskip("distributed")
    from distributed.nanny import _get_env_variables

    from reings.cluster import _worker_environ

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    assert _get_env_variables("distributed.nanny.pre-spawn-environ")["MALLOC_TRIM_THRESHOLD_"] == "65536"
    with _worker_environ():
        env = _get_env_variables("distributed.nanny.pre-spawn-environ")
    assert "MALLOC_TRIM_THRESHOLD_" not in env and env["OMP_NUM_THREADS"] == "1"
    assert _get_env_variables("distributed.nanny.pre-spawn-environ")["MALLOC_TRIM_THRESHOLD_"] == "65536"
