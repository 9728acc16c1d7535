"""bench/host_wait.py (how long the host waits for the device in a whole run, docs/perf_notes.md §18) and
bench/launch_cost.py (what a launch costs the host), on a short `reings run` and a few launches: the stages'
steps, launches and blocking calls counted, the seconds consistent, pyopencl unpatched after."""
from __future__ import annotations

import json

from cases import load_bench, run_tool


def test_host_wait_of_a_run_counts_steps_launches_and_waits_and_restores_its_patches(device, tmp_path):
    import pyopencl as cl
    import pyopencl._cl as _cl

    import reings.pipeline as pipeline
    import reings.train as train

    H = load_bench("host_wait")
    before = (_cl.enqueue_nd_range_kernel, cl.enqueue_copy, cl.enqueue_map_buffer, cl.CommandQueue.finish,
              cl.Event.wait, cl.wait_for_events, pipeline.fit, train._Iteration.__call__)
    out, run_out = tmp_path / "wait.json", tmp_path / "run"
    cmd = ["run", "--device", device, "--preset", "quick", "--iterations", "2,2,3", "--out", str(run_out)]
    assert run_tool(H.main, ["--out", str(out), "--"] + cmd) == 0
    assert (_cl.enqueue_nd_range_kernel, cl.enqueue_copy, cl.enqueue_map_buffer, cl.CommandQueue.finish,
            cl.Event.wait, cl.wait_for_events, pipeline.fit, train._Iteration.__call__) == before
    rep = json.loads(out.read_text())
    st = rep["stages"]
    assert {k: st[k]["iterations"] for k in ("coarse", "fine", "final")} == {"coarse": 2, "fine": 2, "final": 3}
    for k in ("coarse", "fine", "final"):
        s = st[k]
        assert s["launches_per_it"] >= 5 and s["enqueue_us_per_launch"] > 0
        assert 0.0 <= s["blocked_s"] <= s["wall_s"] <= rep["wall_s"]
        assert s["blocking_per_it"] >= 1  # the sync binning reads (V, K) once per forward at least
        assert abs(s["wall_ms_per_it"] * s["iterations"] - 1e3 * s["wall_s"]) < 1e-6 * max(1.0, 1e3 * s["wall_s"])


def test_launch_cost_times_every_way(device, tmp_path):
    L = load_bench("launch_cost")
    path = tmp_path / "launch.jsonl"
    assert L.main(["--device", device, "--launches", "20", "--repeats", "1", "--groups", "4", "--json", str(path)]) == 0
    rows = [json.loads(x) for x in path.read_text().splitlines()]
    assert [(r["way"], r["groups"]) for r in rows] == [(w, g) for g in (1, 4)
                                                     for w in ("invoker", "preset", "noevent", "noevent_preset")]
    assert all(0 < r["enqueue_us"] <= r["wall_us"] for r in rows)
