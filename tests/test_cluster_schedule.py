"""Runs handed to CPU workers of a mixed GPU + CPU cluster (reings.cluster.GridSchedule, list
scheduling): the admission rule on analytic cases, the estimators, a simulation of the driver
over runs of fixed durations against the greedy policy (every idle worker takes the next run),
and `run_grid` on an in-process Dask cluster of one "GPU" and one "CPU" worker running a fake
task."""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import pytest

from reings.cluster import R0, GridSchedule, admit_to_cpu, gpu_estimate, slowdown


def test_admit_to_cpu_analytic():
    # 12 runs of 10 s, 1 GPU slot, R = 20: after the first run, 10 queued + 10 s left on the slot:
    # backlog 110 s; the CPU would take 200 s >= 110 - 10 s: refused
    assert admit_to_cpu([10.0] * 10, 10.0, 1, 20.0) is None
    # 100 runs of 10 s, R = 10: 100 s on the CPU < 1000 - 10 s
    assert admit_to_cpu([10.0] * 100, 0.0, 1, 10.0) == 0
    # the boundary is strict: 21 runs -> 210 - 10 = 200 = 20 * 10; 22 runs -> 210 > 200
    assert admit_to_cpu([10.0] * 21, 0.0, 1, 20.0) is None
    assert admit_to_cpu([10.0] * 22, 0.0, 1, 20.0) == 0
    # the GPU work in flight counts: 21 queued + 10 s on the slot
    assert admit_to_cpu([10.0] * 21, 10.0, 1, 20.0) == 0
    # n_gpu slots share the backlog: 80 runs on 4 slots, 800 / 4 - 2.5 = 197.5 < 200: refused;
    # 84 runs, 210 - 2.5 = 207.5 > 200: admitted
    assert admit_to_cpu([10.0] * 80, 0.0, 4, 20.0) is None
    assert admit_to_cpu([10.0] * 84, 0.0, 4, 20.0) == 0


def test_admit_to_cpu_cheapest_ties_and_empty():
    # the cheapest run goes, the first of equals
    assert admit_to_cpu([30.0, 10.0, 20.0, 10.0] + [50.0] * 20, 0.0, 1, 5.0) == 1
    # the cheapest fails -> nothing goes (a dearer run fails the same test by more)
    costs = [100.0] * 3 + [10.0]
    assert admit_to_cpu(costs, 0.0, 1, 40.0) is None
    assert admit_to_cpu([], 0.0, 1, 20.0) is None
    assert admit_to_cpu([], 1e9, 1, 0.0) is None
    with pytest.raises(ValueError, match="n_gpu"):
        admit_to_cpu([10.0], 0.0, 0, 20.0)


def test_estimators():
    done = {"reings": [10.0, 20.0], "dngaussian": [4.0]}
    assert gpu_estimate("reings", done) == 15.0
    assert gpu_estimate("dngaussian", done) == 4.0
    assert gpu_estimate("3dgs", done) == pytest.approx(34.0 / 3)  # no run of its own: the mean of all
    assert gpu_estimate("reings", {}) is None
    assert slowdown([], done) == R0 == 20.0
    assert slowdown([], done, r0=7.0) == 7.0
    assert slowdown([("reings", 150.0)], {}) == R0  # no GPU run to compare with
    assert slowdown([("reings", 150.0)], done) == 10.0
    # the median of the ratios: 150/15 = 10, 40/4 = 10, 300/15 = 20, 30/4 = 7.5
    obs = [("reings", 150.0), ("dngaussian", 40.0), ("reings", 300.0), ("dngaussian", 30.0)]
    assert slowdown(obs, done) == 10.0
    assert slowdown(obs[:3], done) == 10.0


def test_observed_slowdown_replaces_r0():
    # 30 runs of 10 s on 1 GPU slot; 10 queued + 20 s in flight: backlog 120 s
    s = GridSchedule(["m"] * 14)
    assert s.feed_gpu(1, 0.0) == [0, 1]
    assert s.admit(["cpu"], 1, 0.0) == []  # no GPU run finished: no admission
    s.finished(0, 10.0, 10.0, on_gpu=True)
    assert s.feed_gpu(1, 10.0) == [2]
    assert s.queue == list(range(3, 14)) and s.gpu == {1: 10.0, 2: None} and s.running() == 1
    assert s.gpu_left(15.0) == 15.0  # 5 s of run 1, 10 s of run 2
    # R0 = 20: 200 s >= (110 + 20) - 10: refused
    assert s.admit(["cpu"], 1, 10.0) == []
    # a CPU run measured at 5x: 50 s < 120 s: admitted (the first of the equal runs)
    s.cpu_done.append(("m", 50.0))
    assert s.ratio() == 5.0
    assert s.admit(["cpu"], 1, 10.0) == [(3, "cpu", 50.0, 130.0)]
    assert s.cpu == {3: "cpu"} and s.running() == 2
    # a CPU-submitted run that ran on a GPU worker (its worker died) counts as a GPU run
    s.finished(3, 20.0, 10.0, on_gpu=True)
    assert s.gpu_done["m"] == [10.0, 10.0] and s.cpu == {}
    # a failed or resumed run (no seconds) teaches nothing
    s.finished(1, 20.0)
    assert s.gpu_done["m"] == [10.0, 10.0] and s.gpu == {2: 20.0}


def simulate(gpu_s, cpu_s, n_gpu, n_cpu, policy="list", r0=R0, groups=None):
    """The makespan of runs of fixed durations (gpu_s[i] on a GPU slot, cpu_s[i] on a CPU worker)
    and the runs each CPU worker ran. policy "list": GridSchedule drives it as run_grid does (GPU
    runs wait first in, first out for a slot); "greedy": every idle worker takes the next run
    (all submitted at once, as before)."""
    n = len(gpu_s)
    groups = groups or ["m"] * n
    slots = {("gpu", k): None for k in range(n_gpu)} | {("cpu", k): None for k in range(n_cpu)}  # -> (run, end)
    on_cpu, t, ends = [], 0.0, []
    if policy == "greedy":
        todo = list(range(n))
        while todo or any(slots.values()):
            for w in slots:
                if slots[w] is None and todo:
                    i = todo.pop(0)
                    slots[w] = (i, t + (gpu_s[i] if w[0] == "gpu" else cpu_s[i]))
                    on_cpu += [i] if w[0] == "cpu" else []
            w = min((w for w in slots if slots[w]), key=lambda w: slots[w][1])
            t = slots[w][1]
            ends.append(t)
            slots[w] = None
        return max(ends, default=0.0), on_cpu
    sched, pending = GridSchedule(groups, r0=r0), []

    def step():
        pending.extend(sched.feed_gpu(n_gpu, t))
        for w in slots:
            if w[0] == "gpu" and slots[w] is None and pending:
                i = pending.pop(0)
                slots[w] = (i, t + gpu_s[i])
        idle = [w for w in slots if w[0] == "cpu" and slots[w] is None]
        for i, w, _, _ in sched.admit(idle, n_gpu, t):
            slots[w] = (i, t + cpu_s[i])
            on_cpu.append(i)

    step()
    while any(slots.values()):
        w = min((w for w in slots if slots[w]), key=lambda w: slots[w][1])
        i, t = slots[w]
        ends.append(t)
        slots[w] = None
        sched.finished(i, t, gpu_s[i] if w[0] == "gpu" else cpu_s[i], w[0] == "gpu", n_gpu)
        step()
    assert not sched.queue and not pending and not sched.gpu and not sched.cpu
    assert len(ends) == n
    return max(ends, default=0.0), on_cpu


def test_simulation_analytic():
    # 1 GPU slot of 10 s a run, 1 CPU worker at 20x, 12 runs: the CPU takes nothing, the GPU never
    # idles: 120 s (the greedy policy: 200 s, the CPU's one run)
    assert simulate([10.0] * 12, [200.0] * 12, 1, 1) == (120.0, [])
    assert simulate([10.0] * 12, [200.0] * 12, 1, 1, "greedy") == (200.0, [1])
    # 40 runs: the CPU takes one at t = 10 (370 + 20 s of GPU work left > 200 + 10), ends at 210;
    # then 16 runs queued: refused; the GPU runs the other 39: 390 s (greedy: 400 s)
    assert simulate([10.0] * 40, [200.0] * 40, 1, 1) == (390.0, [3])
    assert simulate([10.0] * 40, [200.0] * 40, 1, 1, "greedy")[0] == 400.0
    # only the GPU: n runs in n * 10 s, as fed ahead
    assert simulate([10.0] * 7, [200.0] * 7, 1, 0) == (70.0, [])
    assert simulate([], [], 1, 1) == (0.0, [])


@pytest.mark.parametrize("n,n_gpu,n_cpu,ratio", [
    (12, 1, 3, 20.0), (12, 1, 3, 10.0), (36, 6, 2, 20.0), (40, 1, 1, 20.0), (100, 1, 3, 20.0),
    (100, 2, 3, 27.0), (200, 1, 4, 10.0), (60, 4, 8, 20.0)])
def test_simulation_not_worse_than_greedy(n, n_gpu, n_cpu, ratio):
    # two methods of unlike costs (reings ~2x dngaussian), the CPU `ratio` x slower, R0 = 20
    gpu = [(20.0 if i % 2 else 10.0) + (i % 3) for i in range(n)]
    groups = ["reings" if i % 2 else "dngaussian" for i in range(n)]
    cpu = [ratio * g for g in gpu]
    listed, on_cpu = simulate(gpu, cpu, n_gpu, n_cpu, groups=groups)
    greedy, _ = simulate(gpu, cpu, n_gpu, n_cpu, "greedy", groups=groups)
    gpu_alone, _ = simulate(gpu, cpu, n_gpu, 0, groups=groups)
    assert listed <= greedy
    assert listed <= gpu_alone  # a CPU run is admitted only where it ends before the GPUs would
    if on_cpu:
        assert listed < gpu_alone


def test_every_group_measured_before_a_cpu_run():
    """The GPU takes the first run of each unmeasured method early; no CPU run until each queued
    method has a GPU time (costed at another method's mean, a cheap method would swell the backlog)."""
    s = GridSchedule(["reings"] * 20 + ["dngaussian"] * 20)
    assert s.feed_gpu(1, 0.0) == [0, 20]  # the first dngaussian run jumps the queue
    assert s.feed_gpu(1, 0.0) == []
    s.finished(0, 18.0, 18.0, on_gpu=True, n_gpu=1)
    assert s.feed_gpu(1, 18.0) == [1]
    assert s.admit(["cpu"], 1, 18.0) == []  # dngaussian not measured yet (the backlog would be 38 x 18 s)
    s.finished(20, 26.0, 8.0, on_gpu=True, n_gpu=1)
    assert s.feed_gpu(1, 26.0) == [2]
    # queued: 17 reings x 18 + 19 dngaussian x 8 = 458 s; on the slot: run 1 (just started) and
    # run 2, 2 x 18 s: backlog 494 s; the cheapest, dngaussian run 21: 20 x 8 < 494 - 8
    assert s.admit(["cpu"], 1, 26.0) == [(21, "cpu", 160.0, 494.0)]


@pytest.mark.parametrize("true_r", [10.0, 12.0, 20.0, 27.0, 35.0])
@pytest.mark.parametrize("methods_outer", [False, True])
def test_simulation_measured_times(true_r, methods_outer):
    """The H100's quick LLFF times (bench/results/h100_session7: dngaussian ~8 s, reings ~18 s on
    the GPU), 1 GPU slot + 3 CPU workers, a CPU slowdown from 10x to beyond R0: 12 runs stay on the
    GPU; 36 and 120 runs end before the GPU alone would. The greedy hand-out can end up to 3 %
    sooner where the CPU is much faster than R0 says and the cheap runs come last (36 runs, all
    reings first, 10x: 372 s against 360 s); elsewhere, up to 2x later."""
    for n in (12, 36, 120):
        k = n // 12
        if methods_outer:  # the grid's order: all of one method, then the other
            groups = [m for m in ("reings", "dngaussian") for _ in range(6 * k)]
        else:
            groups = [m for _ in range(6 * k) for m in ("reings", "dngaussian")]
        gpu = [18.0 if m == "reings" else 8.0 for m in groups]
        cpu = [true_r * g for g in gpu]
        listed, on_cpu = simulate(gpu, cpu, 1, 3, groups=groups)
        greedy, _ = simulate(gpu, cpu, 1, 3, "greedy", groups=groups)
        gpu_alone, _ = simulate(gpu, cpu, 1, 0, groups=groups)
        assert listed <= gpu_alone and listed <= 1.04 * greedy, (n, listed, greedy, gpu_alone)
        assert (on_cpu == []) == (n == 12) and (n == 12 or listed < gpu_alone)


def _fake_run(cfg) -> dict:
    """run_task's stand-in: `cfg.gpu_s` on the "gpu" worker, 20x on the others; raises for "bad"."""
    from distributed import get_worker

    w = get_worker()
    if cfg.bad:
        raise RuntimeError("bad data")
    gpu = str(w.name).startswith("gpu")
    s = cfg.gpu_s * (1 if gpu else 20)
    time.sleep(s)
    return {"out": cfg.output.out, "status": "ran", "seconds": s, "device": "gpu" if gpu else "cpu",
            "worker": w.address}


def _inproc_cluster(cpu_workers=1):
    distributed = pytest.importorskip("distributed")
    from distributed.deploy.spec import SpecCluster

    workers = {"gpu-0": {"cls": distributed.Worker, "options": {"nthreads": 1, "resources": {"RUN": 1, "GPU": 1}}}}
    workers |= {f"cpu-{k}": {"cls": distributed.Worker, "options": {"nthreads": 1, "resources": {"RUN": 1}}}
                for k in range(cpu_workers)}
    scheduler = {"cls": distributed.Scheduler, "options": {"dashboard_address": ":0"}}
    cluster = SpecCluster(workers=workers, scheduler=scheduler, asynchronous=False, silence_logs=40)
    return cluster, distributed.Client(cluster)


def _jobs(tmp_path, n, gpu_s, bad=()):
    return [("procedural", "s", SimpleNamespace(method="reings" if i % 2 else "dngaussian", gpu_s=gpu_s,
                                                bad=i in bad, output=SimpleNamespace(out=str(tmp_path / f"run{i}"))))
            for i in range(n)]


def test_run_grid_mixed_short_grid_stays_on_the_gpu(tmp_path, monkeypatch):
    """12 runs: the CPU worker is never worth a run; a run that raises is reported, the rest go on."""
    from reings import cluster as cl

    monkeypatch.setattr(cl, "run_task", _fake_run)
    cluster, client = _inproc_cluster()
    try:
        lines = []
        failed = cl.run_grid(client, _jobs(tmp_path, 12, 0.05, bad={5}), quiet=True, say=lines.append)
    finally:
        client.close()
        cluster.close()
    assert [f[0] for f in failed] == [str(tmp_path / "run5")]
    runs = [ln for ln in lines if ln.startswith("[")]
    assert len(runs) == 12 and sorted(int(ln[1:].split("/")[0]) for ln in runs) == list(range(1, 13))
    assert sum("FAILED: RuntimeError: bad data" in ln for ln in runs) == 1
    assert all("on cpu" not in ln for ln in runs) and not any("-> CPU worker" in ln for ln in lines)
    assert "1 GPU slot(s), 1 CPU slot(s)" in lines[1]


def test_run_grid_mixed_long_grid_feeds_the_cpu(tmp_path, monkeypatch):
    """60 runs of 0.05 s on the GPU, 1 s on the CPU: the CPU worker takes runs (R * c = 1 s against
    ~2.9 s of GPU work queued after the first run)."""
    from reings import cluster as cl

    monkeypatch.setattr(cl, "run_task", _fake_run)
    cluster, client = _inproc_cluster()
    try:
        lines = []
        failed = cl.run_grid(client, _jobs(tmp_path, 60, 0.05), quiet=True, say=lines.append)
    finally:
        client.close()
        cluster.close()
    assert failed == []
    runs = [ln for ln in lines if ln.startswith("[")]
    assert len(runs) == 60
    assert any("on cpu" in ln for ln in runs) and any("-> CPU worker" in ln for ln in lines)
    assert sum("on cpu" in ln for ln in runs) == sum("-> CPU worker" in ln for ln in lines)


def test_run_grid_mixed_cpu_worker_dies(tmp_path, monkeypatch):
    """A CPU worker closed during its 2 s run: the run is held to that worker only loosely
    (allow_other_workers), so Dask reruns it elsewhere and the grid completes."""
    from reings import cluster as cl

    monkeypatch.setattr(cl, "run_task", _fake_run)
    cluster, client = _inproc_cluster()
    try:
        lines, result = [], {}
        t = threading.Thread(target=lambda: result.setdefault(
            "failed", cl.run_grid(client, _jobs(tmp_path, 60, 0.1), quiet=True, say=lines.append)))
        t.start()
        deadline = time.time() + 60
        while not any("-> CPU worker" in ln for ln in lines):
            assert time.time() < deadline and t.is_alive(), lines
            time.sleep(0.02)
        cluster.sync(cluster.workers["cpu-0"].close)  # the CPU worker leaves mid-run, for good
        t.join(timeout=120)
        assert not t.is_alive()
    finally:
        client.close()
        cluster.close()
    assert result["failed"] == []
    runs = [ln for ln in lines if ln.startswith("[")]
    assert len(runs) == 60
    # the run admitted to the CPU worker (2 s there) was rerun on the GPU worker
    moved = [ln for ln in lines if "-> CPU worker" in ln][0].split()[0]
    assert [ln.endswith("on gpu)") for ln in runs if f" {moved}: " in ln] == [True]


def test_slots_of_the_workers():
    """GPU slots: workers offering GPU (min(threads, GPU)); CPU workers: RUN without GPU; others: none."""
    from reings.cluster import _slots

    ws = {"g1": {"resources": {"RUN": 1, "GPU": 1}, "nthreads": 1},
          "g2": {"resources": {"RUN": 2, "GPU": 2}, "nthreads": 4},
          "c1": {"resources": {"RUN": 1}, "nthreads": 1},
          "c2": {"resources": {"RUN": 3}, "nthreads": 2},
          "plain": {"resources": {}, "nthreads": 8}}
    assert _slots(ws) == (3, {"c1": 1, "c2": 2})
    assert _slots({}) == (0, {})
