"""The OpenCL programs a whole `reings` command builds, and what building them in parallel would save
(issue 15: a fresh machine's first run carries every build on its training clock).

    python bench/bench_builds.py record --out builds.json -- eval --dataset llff --root DATA/llff \
        --scenes fern --views 3 --seeds 0 --methods reings --preset paper --device cuda:0 --no-lpips
    python bench/bench_builds.py replay builds.json --device cuda:0 --threads 1,8

record: runs the `reings` command line after `--` with KernelLibrary.program wrapped: every program
built (file, defines), in order, with its wall seconds and the fitting stage whose `fit` call built it
(the `desc` of each `reings.pipeline.fit` call, the trainer's construction and the programs built
before the fit's clock included: metrics.json `kernel_builds_on_clock` says what fell on the clock;
"other" outside fits); writes them and the per-stage totals to --out (JSON).
replay: in this fresh process, builds the recorded programs again, on a new context each round, with
1, 8, ... threads (pyopencl's build releases the GIL; OpenCL's API is thread safe). What is cold
depends on the on-disk caches (pyopencl's and the driver's, e.g. NVIDIA's ~/.nv/ComputeCache): clear
them before a round to time a fresh machine. Prints one JSON line per round.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def record(out: str, cmd: list) -> int:
    from reings import pipeline
    from reings.backends.opencl import program
    from reings.cli import main as reings_main

    stage = ["other"]
    builds = []
    orig_program, orig_fit = program.KernelLibrary.program, pipeline.fit

    def prog(self, filename, **defines):
        key = (filename, tuple(sorted(defines.items())))
        if key in self._programs:
            return orig_program(self, filename, **defines)
        t = time.perf_counter()
        prg = orig_program(self, filename, **defines)  # a failed build raises: not recorded
        builds.append({"file": filename, "defines": dict(defines), "stage": stage[0],
                       "seconds": time.perf_counter() - t, "device": self.device.name})
        return prg

    def fit(*args, **kw):
        prev, stage[0] = stage[0], str(kw.get("desc") or "fit")
        try:
            return orig_fit(*args, **kw)
        finally:
            stage[0] = prev

    program.KernelLibrary.program, pipeline.fit = prog, fit
    try:
        rc = reings_main(cmd)
    finally:
        program.KernelLibrary.program, pipeline.fit = orig_program, orig_fit
    per = collections.defaultdict(lambda: {"programs": 0, "seconds": 0.0})
    for b in builds:
        per[b["stage"]]["programs"] += 1
        per[b["stage"]]["seconds"] += b["seconds"]
    rep = {"command": cmd, "rc": rc, "programs": len(builds), "seconds": sum(b["seconds"] for b in builds),
           "per_stage": dict(per), "builds": builds}
    with open(out, "w") as f:
        json.dump(rep, f, indent=1)
    print(json.dumps({k: rep[k] for k in ("programs", "seconds", "per_stage")}))
    return int(rc or 0)


def replay(path: str, device: str, threads: list) -> int:
    import pyopencl as cl

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.program import KernelLibrary

    os.environ["REINGS_CL_VERBOSE"] = "1"  # the build's stderr redirect (program._compiler_output) is per process
    with open(path) as f:
        rec = json.load(f)
    h = open_device(device)
    seen, todo = set(), []
    for b in rec["builds"]:
        key = (b["file"], tuple(sorted(b["defines"].items())))
        if key not in seen:
            seen.add(key)
            todo.append(b)
    for n in threads:
        ctx = cl.Context([h.device])  # a new context: nothing of an earlier round in memory
        lib = KernelLibrary(ctx, h.device)
        t = time.perf_counter()
        with ThreadPoolExecutor(max_workers=n) as ex:
            list(ex.map(lambda b: lib.program(b["file"], **b["defines"]), todo))
        print(json.dumps({"threads": n, "programs": len(todo), "wall_s": time.perf_counter() - t,
                          "sum_build_s": lib.build_seconds, "device": h.device.name}), flush=True)
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cmd = []
    if "--" in argv:
        i = argv.index("--")
        argv, cmd = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    r = sub.add_parser("record")
    r.add_argument("--out", required=True)
    p = sub.add_parser("replay")
    p.add_argument("builds")
    p.add_argument("--device", default="pocl")
    p.add_argument("--threads", default="1,8")
    a = ap.parse_args(argv)
    if a.what == "record":
        if not cmd:
            ap.error("record needs a reings command line after --")
        return record(a.out, cmd)
    return replay(a.builds, a.device, [int(x) for x in a.threads.split(",")])


if __name__ == "__main__":
    sys.exit(main())
