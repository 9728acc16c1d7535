"""How long the host waits for the device in a whole `reings` command (issue 15: host- or device-bound?).

    python bench/host_wait.py --out wait.json -- eval --dataset llff --root DATA/llff --scenes fern \
        --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips --out /tmp/r

Everything after `--` is a `reings` command line. The calls that block the host on the queue are
wrapped with a clock (blocking reads and writes through `pyopencl.enqueue_copy`, blocking maps,
`CommandQueue.finish`, `Event.wait`, `pyopencl.wait_for_events`), as are the kernel launches (their
count, and the time the enqueue call itself took: Python's invoker, the driver's argument setting
and enqueue). Per fitting stage (the `desc` of each `reings.train.fit` call, as in
bench/kernel_census.py; "other" outside fits): iterations, wall seconds, seconds blocked, launches
per iteration and the host's enqueue microseconds per launch.

Reading it: a fit whose host waits for a large share of its wall time is bound by the device (its
kernels, or the queue's latency between them); one that hardly waits is bound by the host (Python
and the driver's enqueue): the GPU finished each command before the host had enqueued the next, so
only a cheaper host step, or fewer commands, makes it faster. Nothing here turns on the queue's
profiling, so the run's own speed is hardly changed (a clock read per wrapped call).
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


class Waits:
    """Seconds blocked, blocking calls, launches and their enqueue time, per stage."""

    def __init__(self):
        self.stage = "other"
        self.blocked = collections.Counter()  # stage -> seconds inside blocking calls
        self.blocking = collections.Counter()  # stage -> blocking calls
        self.launches = collections.Counter()  # stage -> kernel launches
        self.enqueue = collections.Counter()  # stage -> seconds inside the launch entry point
        self.wall = collections.Counter()  # stage -> wall seconds of its fits
        self.iterations = collections.Counter()

    def report(self) -> dict:
        out = {}
        for stage in sorted(set(self.wall) | set(self.blocked) | set(self.launches)):
            its = int(self.iterations.get(stage, 0))
            per = max(its, 1)
            wall = self.wall.get(stage, 0.0)
            n = self.launches.get(stage, 0)
            out[stage] = {"iterations": its, "wall_s": wall, "blocked_s": self.blocked.get(stage, 0.0),
                          "blocked_share": self.blocked.get(stage, 0.0) / wall if wall else None,
                          "blocking_per_it": self.blocking.get(stage, 0) / per,
                          "launches_per_it": n / per,
                          "wall_ms_per_it": 1e3 * wall / per if its else None,
                          "blocked_ms_per_it": 1e3 * self.blocked.get(stage, 0.0) / per if its else None,
                          "enqueue_us_per_launch": 1e6 * self.enqueue.get(stage, 0.0) / n if n else None}
        return out


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        raise SystemExit("usage: host_wait.py [--out F] -- <reings command line>")
    i = argv.index("--")
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="write the table as JSON")
    a = ap.parse_args(argv[:i])
    cmd = argv[i + 1:]

    import numpy as np
    import pyopencl as cl
    import pyopencl._cl as _cl

    import reings.pipeline as pipeline
    import reings.train as train
    from reings.cli import main as reings_main

    w = Waits()
    clock = time.perf_counter
    saved = []

    def patch(obj, name, make):
        orig = getattr(obj, name)
        saved.append((obj, name, orig))
        setattr(obj, name, make(orig))

    def timed(orig):  # a call that always blocks
        def f(*args, **kw):
            t = clock()
            try:
                return orig(*args, **kw)
            finally:
                w.blocked[w.stage] += clock() - t
                w.blocking[w.stage] += 1
        return f

    def copy(orig):  # blocks when is_blocking (the default) and one side is host memory
        def f(queue, dest, src, **kw):
            if kw.get("is_blocking", True) and (isinstance(dest, np.ndarray) or isinstance(src, np.ndarray)):
                return timed(orig)(queue, dest, src, **kw)
            return orig(queue, dest, src, **kw)
        return f

    def mapb(orig):
        def f(*args, **kw):
            if kw.get("is_blocking", True):
                return timed(orig)(*args, **kw)
            return orig(*args, **kw)
        return f

    def launch(orig):
        def f(*args, **kw):
            t = clock()
            try:
                return orig(*args, **kw)
            finally:
                w.enqueue[w.stage] += clock() - t
                w.launches[w.stage] += 1
        return f

    def fit(orig):
        def f(*args, **kw):
            prev, w.stage = w.stage, str(kw.get("desc") or "fit")
            t = clock()
            try:
                return orig(*args, **kw)
            finally:
                w.wall[w.stage] += clock() - t
                w.stage = prev
        return f

    def step(orig):
        def f(self, it):
            w.iterations[w.stage] += 1
            return orig(self, it)
        return f

    patch(_cl, "enqueue_nd_range_kernel", launch)
    patch(cl, "enqueue_copy", copy)
    patch(cl, "enqueue_map_buffer", mapb)
    patch(cl.CommandQueue, "finish", timed)
    patch(cl.Event, "wait", timed)
    patch(cl, "wait_for_events", timed)
    patch(pipeline, "fit", fit)
    patch(train._Iteration, "__call__", step)
    t0 = clock()
    try:
        rc = reings_main(cmd)
    finally:
        for obj, name, orig in reversed(saved):
            setattr(obj, name, orig)
    total = clock() - t0
    rep = w.report()
    for stage, r in rep.items():
        per = f"  wall {r['wall_ms_per_it']:.3f} ms/it  blocked {r['blocked_ms_per_it']:.3f} ms/it" if r["iterations"] else ""
        enq = r["enqueue_us_per_launch"]
        print(f"{stage:10s} its {r['iterations']:6d}  wall {r['wall_s']:7.2f} s  blocked {r['blocked_s']:7.2f} s"
              f"{per}  blocking/it {r['blocking_per_it']:.2f}  launches/it {r['launches_per_it']:.1f}  "
              f"enqueue {enq if enq is None else round(enq, 2)} us/launch", flush=True)
    print(f"command wall {total:.2f} s", flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"command": cmd, "wall_s": total, "stages": rep}, f, indent=1)
    return rc


if __name__ == "__main__":
    sys.exit(main())
