"""An ensemble's members (`--ensemble K`, docs/method.md §13): each member runs the stages from
`--ensemble-from` on, one after another in this process, or with `--ensemble-jobs J` > 1 up to J at
once: member 0 here, the others each in a worker process of its own on the same device (the
same bits; on one H100 5-11 % less wall time, docs/results.md §36).

    members = fit_members(ctx, stages, split, k, jobs)   # [RunContext], member 0 = ctx

A worker is `python -m reings.ensemble_worker IN OUT` (started through `python -c` and runpy so that
this package, not the current folder, comes first on its path): it reads its member's inputs (the run's config,
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
    stages `stages[:split]`), `jobs` at a time: in each round one member fits here while up to
    jobs - 1 others fit in worker processes."""
    members = [ctx] + [ctx.member(i, ctx.g) for i in range(1, k)]
    queue = list(members)
    while queue:
        here, others, queue = queue[0], queue[1:max(jobs, 1)], queue[max(jobs, 1):]
        with _Workers(ctx, others, split) as workers:
            for name, stage in stages[split:]:
                here.g = stage(here, name)
            workers.collect()
    return members


class _Workers:
    """Worker processes, one per member of `batch`, started on entry; `collect` waits for them
    and copies each member's records into its context. Leaving early (an exception, Ctrl-C, also
    while starting them) terminates the ones still running and removes their files; a worker
    whose parent dies (its stdin pipe closes) exits too (`reings.ensemble_worker`)."""

    def __init__(self, ctx, batch: list, split: int):
        self.ctx, self.batch, self.split = ctx, batch, split
        self.dir = tempfile.mkdtemp(prefix="reings-members-") if batch else None
        self.procs = []

    def __enter__(self):
        try:
            for mk in self.batch:
                src, dst, log = (os.path.join(self.dir, f"member{mk.member_index}.{s}") for s in ("in", "out", "log"))
                with open(src, "wb") as f:
                    pickle.dump(_payload(mk, self.split), f, protocol=pickle.HIGHEST_PROTOCOL)
                with open(log, "wb") as out:  # a file, not a pipe: a full pipe would stall the worker
                    p = subprocess.Popen(_worker_command(src, dst), stdin=subprocess.PIPE, stdout=out,
                                         stderr=subprocess.STDOUT)
                self.procs.append((mk, dst, log, p))
        except BaseException:
            self.__exit__(None, None, None)
            raise
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
            if p.stdin is not None:
                p.stdin.close()
        if self.dir:
            shutil.rmtree(self.dir, ignore_errors=True)
        return False


def _worker_command(src: str, dst: str) -> list:
    """`python -m reings.ensemble_worker SRC DST` with this very package first on the path (not the
    current folder, which `-m` would put first: a checkout there must not shadow the package
    the run imported)."""
    boot = (f"import runpy, sys; sys.path[0] = {_package_root()!r}; "
            "runpy.run_module('reings.ensemble_worker', run_name='__main__', alter_sys=True)")
    return [sys.executable, "-c", boot, src, dst]


def _package_root() -> str:
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _payload(mk, split: int) -> dict:
    """What a worker needs to run member `mk` (a RunContext from RunContext.member): its whole
    state but the device handle, the logger and the progress flag (`ensemble_worker.run_member`
    restores it), so a worker's context is the in-process one."""
    state = {key: v for key, v in vars(mk).items() if key not in ("backend", "log", "progress")}
    return {"state": state, "split": split}
