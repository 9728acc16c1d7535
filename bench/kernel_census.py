"""Kernel census of a whole `reings` command (issue 15): every kernel launch of the run, per fitting
stage and kernel name: launches per iteration, device milliseconds (profiling events, end - start)
and the idle gaps between commands of the in-order queue.

    python bench/kernel_census.py --out census.json -- eval --dataset llff --root DATA/llff --scenes fern \
        --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out /tmp/r

Everything after `--` is a `reings` command line. pyopencl's launch entry point is wrapped (as
`reings.backends.opencl.harness.ClCalls` does); every `--window` launches the host waits for the
last one and folds the window's events: per kernel name the launch count and the summed execution
time, per window the span (first start to last end) and the gaps (the span minus the execution
time of the kernels in it; copies and fills between kernels count as gaps). The waits make the run
slightly slower (one per window); the default window of 4096 launches is about 50 iterations of a
full-schedule fit. The stage of a launch is the `desc` of the `reings.train.fit` call it ran in
("coarse", "fine", "final", "3dgs", ...), its test-PSNR probes "<fit>/probe", "other" outside fits (the
IVPS / CVPS renders, the final test renders). Iterations are the fit loop's steps as run (a resumed fit runs
fewer than its recipe's); stages without steps report totals ("its 0").

Prints, per stage: iterations, wall seconds of the fit, launches / iteration, device busy ms /
iteration, gap ms / iteration, and the kernels by device time; --out writes the same as JSON.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


class Census:
    """Launch records folded per (stage, kernel name); see the module docstring."""

    def __init__(self, window: int):
        self.window = window
        self.stage = "other"
        self.pending: list = []  # (stage, name, event)
        self.count = collections.Counter()  # (stage, name) -> launches
        self.ms = collections.Counter()  # (stage, name) -> summed end - start, ms
        self.span = collections.Counter()  # stage -> summed window spans, ms
        self.busy = collections.Counter()  # stage -> summed execution in those windows, ms
        self.wall = collections.Counter()  # stage -> wall seconds of its fits
        self.iterations = collections.Counter()  # stage -> iterations of its fits

    def record(self, name: str, ev) -> None:
        self.pending.append((self.stage, name, ev))
        if len(self.pending) >= self.window:
            self.fold()

    def fold(self) -> None:
        if not self.pending:
            return
        self.pending[-1][2].wait()
        by_stage: dict = collections.defaultdict(list)
        for stage, name, ev in self.pending:
            s, e = ev.profile.start, ev.profile.end
            self.count[(stage, name)] += 1
            self.ms[(stage, name)] += (e - s) * 1e-6
            by_stage[stage].append((s, e))
        for stage, se in by_stage.items():
            se.sort()
            busy = sum(e - s for s, e in se) * 1e-6
            self.busy[stage] += busy
            self.span[stage] += (se[-1][1] - se[0][0]) * 1e-6
        self.pending = []

    def report(self) -> dict:
        self.fold()
        out = {}
        for stage in sorted({s for s, _ in self.count}):
            its = max(int(self.iterations.get(stage, 0)), 1)  # 0 steps (probes, other): totals
            kern = {n: {"launches_per_it": c / its, "ms_per_it": self.ms[(stage, n)] / its}
                    for (s, n), c in self.count.items() if s == stage}
            out[stage] = {"iterations": int(self.iterations.get(stage, 0)), "wall_s": self.wall.get(stage, 0.0),
                          "launches_per_it": sum(k["launches_per_it"] for k in kern.values()),
                          "busy_ms_per_it": self.busy[stage] / its,
                          "gap_ms_per_it": (self.span[stage] - self.busy[stage]) / its,
                          "kernels": dict(sorted(kern.items(), key=lambda kv: -kv[1]["ms_per_it"]))}
        return out


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        raise SystemExit("usage: kernel_census.py [--out F] [--window N] -- <reings command line>")
    i = argv.index("--")
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="write the census as JSON")
    ap.add_argument("--window", type=int, default=4096, help="launches between the host's folds (waits)")
    a = ap.parse_args(argv[:i])
    cmd = argv[i + 1:]

    import pyopencl._cl as _cl

    import reings.pipeline as pipeline
    import reings.train as train
    from reings.backends import set_queue_profiling
    from reings.cli import main as reings_main

    set_queue_profiling(True)  # the census reads every launch's profiling event (restored below)

    census = Census(a.window)
    orig_launch = _cl.enqueue_nd_range_kernel

    orig_fit = train.fit
    orig_step = train._Iteration.__call__
    orig_probe = pipeline.RunContext.probe
    names: dict = {}  # cl.Kernel -> function name (one OpenCL query per kernel, not per launch)

    def launch(queue, kernel, *args, **kw):
        ev = orig_launch(queue, kernel, *args, **kw)
        name = names.get(kernel)
        if name is None:
            name = names[kernel] = kernel.function_name
        census.record(name, ev)
        return ev

    def fit(*args, **kw):
        prev, census.stage = census.stage, str(kw.get("desc") or "fit")
        t = time.perf_counter()
        try:
            return orig_fit(*args, **kw)
        finally:
            try:
                census.fold()
            finally:
                census.wall[census.stage] += time.perf_counter() - t
                census.stage = prev

    def step(self, it):  # the iterations a fit runs (a resumed fit runs fewer than its recipe's)
        census.iterations[census.stage] += 1
        return orig_step(self, it)

    def probe(self, g):  # the test-PSNR probes inside a fit: a stage of their own, "<fit>/probe"
        prev, census.stage = census.stage, census.stage + "/probe"
        try:
            return orig_probe(self, g)
        finally:
            census.stage = prev

    _cl.enqueue_nd_range_kernel = launch
    pipeline.fit = fit
    train._Iteration.__call__ = step
    pipeline.RunContext.probe = probe
    try:
        rc = reings_main(cmd)
    finally:
        set_queue_profiling(None)
        _cl.enqueue_nd_range_kernel = orig_launch
        pipeline.fit = orig_fit
        train._Iteration.__call__ = orig_step
        pipeline.RunContext.probe = orig_probe
    rep = census.report()
    for stage, r in rep.items():
        print(f"{stage:10s} its {r['iterations']:6d}  wall {r['wall_s']:7.2f} s  launches/it {r['launches_per_it']:6.1f}  "
              f"busy {r['busy_ms_per_it']:.3f} ms/it  gaps {r['gap_ms_per_it']:.3f} ms/it")
        print("    " + "  ".join(f"{n} {k['ms_per_it']:.3f}/{k['launches_per_it']:.2f}"
                                 for n, k in r["kernels"].items()))
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"command": cmd, "window": a.window, "stages": rep}, f, indent=1)
    return rc


if __name__ == "__main__":
    sys.exit(main())
