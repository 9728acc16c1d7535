"""An ensemble's members (`--ensemble K`, docs/method.md §13): each member runs the stages from
`--ensemble-from` on, one after another in this process, or with `--ensemble-jobs J` > 1 up to J at
once: member 0 here, the others each in a worker process of its own on the same device (the
same bits; on one H100 5-11 % less wall time, docs/results.md §36).

    members = fit_members(ctx, stages, split, k, jobs)   # [RunContext], member 0 = ctx

A worker is `python -m reings.ensemble_worker IN OUT`: it reads its member's inputs (the run's config,
training and test views, priors, scene box and the shared stages' model) from the pickle IN, opens
its own backend for the run's device, runs the member's stages and writes the member's model,
records and log lines to OUT. A subprocess, not multiprocessing: a library must not re-import its
caller's main module (multiprocessing's spawn does), and a device context must not be forked. The
fits are deterministic, so a member is the same bits in a worker as in this process
(`tests/test_ensemble.py`); killed, a worker leaves its checkpoints as a fit in this process does.
"""
from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile

RECORDS = ("g", "clock", "timings", "counts", "model_bytes", "stages", "series", "bounds")  # a member's results


def jobs_of(cfg, k: int) -> int:
    """How many members fit at once: RunConfig.ensemble_jobs (at most K). One by default: on one
    H100 two members at once took a DTU run 108 -> 96-103 s end to end and fern 72 -> 64 s (the
    members share the GPU: each fit ran 1.7x slower; docs/results.md §36), and on a CPU one fit
    already keeps the cores busy."""
    return max(1, min(int(cfg.ensemble_jobs), k))


def fit_members(ctx, stages: list, split: int, k: int, jobs: int = 1) -> list:
    """The K members' contexts after their stages (member 0 is `ctx`, which has run the shared
    stages `stages[:split]`); `jobs` members at a time."""
    members = [ctx] + [ctx.member(i, ctx.g) for i in range(1, k)]
    if jobs <= 1:
        for mk in members:
            for name, stage in stages[split:]:
                mk.g = stage(mk, name)
        return members
    first, rest = members[1:jobs], members[jobs:]
    with _Workers(ctx, first, split) as workers:  # member 0 here meanwhile
        for name, stage in stages[split:]:
            ctx.g = stage(ctx, name)
        workers.collect()
    while rest:
        batch, rest = rest[:jobs], rest[jobs:]
        with _Workers(ctx, batch, split) as workers:
            workers.collect()
    return members


class _Workers:
    """Worker processes, one per member of `batch`, started on entry; `collect` waits for them
    and copies each member's records into its context; leaving early (an exception, Ctrl-C)
    terminates the ones still running."""

    def __init__(self, ctx, batch: list, split: int):
        self.ctx, self.batch, self.split = ctx, batch, split
        self.dir = tempfile.mkdtemp(prefix="reings-members-")
        self.procs = []

    def __enter__(self):
        env = dict(os.environ)  # the worker imports this very package
        env["PYTHONPATH"] = os.pathsep.join([_package_root()] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
                                                                 if p])
        for mk in self.batch:
            src, dst, log = (os.path.join(self.dir, f"member{mk.member_index}.{s}") for s in ("in", "out", "log"))
            with open(src, "wb") as f:
                pickle.dump(_payload(mk, self.split), f, protocol=pickle.HIGHEST_PROTOCOL)
            with open(log, "wb") as out:  # a file, not a pipe: a full pipe would stall the worker
                p = subprocess.Popen([sys.executable, "-m", "reings.ensemble_worker", src, dst], env=env,
                                     stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT)
            self.procs.append((mk, dst, log, p))
        return self

    def collect(self) -> None:
        for mk, dst, log, p in self.procs:
            p.wait()
            if p.returncode != 0 or not os.path.exists(dst):
                with open(log, "rb") as f:
                    tail = f.read().decode("utf-8", "replace").strip().splitlines()[-15:]
                raise RuntimeError(f"ensemble member {mk.member_index}: its worker process failed (exit code "
                                   f"{p.returncode}):\n" + "\n".join(tail))
            with open(dst, "rb") as f:
                r = pickle.load(f)
            for line in r.pop("log"):
                self.ctx.log(f"(member {mk.member_index}) {line}")
            for key in RECORDS:
                setattr(mk, key, r[key])

    def __exit__(self, *exc):
        import shutil

        for *_, p in self.procs:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        shutil.rmtree(self.dir, ignore_errors=True)
        return False


def _package_root() -> str:
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _payload(mk, split: int) -> dict:
    """What a worker needs to run member `mk` (a RunContext from RunContext.member)."""
    return {"cfg": mk.cfg, "k": mk.member_index, "g": mk.g, "split": split, "train": mk.train, "test": mk.test,
            "priors": mk.priors, "confidences": mk.confidences, "box": mk.box, "family": mk.family,
            "prior_options": mk.prior_options, "in_memory": mk.in_memory}
