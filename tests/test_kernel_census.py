"""bench/kernel_census.py's folding (the whole-run kernel census of docs/perf_notes.md §11), on fake profiling
events with known start / end times: launches and device ms per (stage, kernel), busy time and queue gaps per
stage, per-iteration division; and that the fold waits for the window's last event."""
from __future__ import annotations

from cases import load_bench, run_tool


def _census_module():
    return load_bench("kernel_census")


class _Prof:
    def __init__(self, start, end):
        self.start, self.end = start, end


class _Event:
    waited = 0

    def __init__(self, start_ns, end_ns):
        self.profile = _Prof(start_ns, end_ns)

    def wait(self):
        _Event.waited += 1


def test_census_folds_counts_busy_and_gaps():
    K = _census_module()
    c = K.Census(window=3)
    ms = 1_000_000  # ns per ms
    c.stage = "coarse"
    c.record("a", _Event(0 * ms, 2 * ms))      # busy 2
    c.record("b", _Event(3 * ms, 4 * ms))      # gap 1, busy 1
    c.record("a", _Event(10 * ms, 11 * ms))    # gap 6, busy 1: the window (3 launches) folds here
    assert _Event.waited == 1 and not c.pending
    c.stage = "fine"
    c.record("b", _Event(20 * ms, 25 * ms))
    c.iterations["coarse"] = 2
    c.iterations["fine"] = 1
    rep = c.report()                           # folds the rest
    co, fi = rep["coarse"], rep["fine"]
    assert co["iterations"] == 2 and fi["iterations"] == 1
    assert abs(co["launches_per_it"] - 1.5) < 1e-12
    assert abs(co["kernels"]["a"]["ms_per_it"] - 1.5) < 1e-9      # (2 + 1) ms / 2 iterations
    assert abs(co["kernels"]["a"]["launches_per_it"] - 1.0) < 1e-12
    assert abs(co["busy_ms_per_it"] - 2.0) < 1e-9                 # 4 ms busy / 2
    assert abs(co["gap_ms_per_it"] - 3.5) < 1e-9                  # span 11 - busy 4 = 7 ms / 2
    assert list(co["kernels"]) == ["a", "b"]                      # largest device time first
    assert abs(fi["busy_ms_per_it"] - 5.0) < 1e-9 and fi["gap_ms_per_it"] == 0.0


def test_census_of_a_run_counts_the_steps_run_and_restores_its_patches(device, tmp_path):
    """The whole tool on a short `reings run`: each fitting stage's steps, the probes in stages of their
    own, launches attributed, and pyopencl / reings unpatched after. (A resumed fit's fewer steps are not
    exercised here: a finished run is not resumed.)"""
    import json

    import pyopencl._cl as _cl

    import reings.pipeline as pipeline
    import reings.train as train

    K = _census_module()
    before = (_cl.enqueue_nd_range_kernel, pipeline.fit, train._Iteration.__call__, pipeline.RunContext.probe)
    out, run_out = tmp_path / "census.json", tmp_path / "run"
    cmd = ["run", "--device", device, "--preset", "quick", "--iterations", "2,2,3", "--out", str(run_out)]
    assert run_tool(K.main, ["--out", str(out), "--window", "64", "--"] + cmd) == 0
    assert (_cl.enqueue_nd_range_kernel, pipeline.fit, train._Iteration.__call__, pipeline.RunContext.probe) == before
    st = json.loads(out.read_text())["stages"]
    assert {k: st[k]["iterations"] for k in ("coarse", "fine", "final")} == {"coarse": 2, "fine": 2, "final": 3}
    assert "final/probe" in st and st["final/probe"]["iterations"] == 0
    assert st["coarse"]["kernels"]["rasterize_fwd"]["launches_per_it"] >= 1
