"""`reings eval --cluster`: an evaluation grid as Dask tasks (optional extra `cluster`).

    reings eval ... --cluster local            one worker per device: every NVIDIA GPU when --device
                                               is cuda, else one PoCL worker
    reings eval ... --cluster local:N          N workers: the GPUs first (--device cuda), the others
                                               PoCL workers sharing the spare cores
    reings eval ... --runs-per-gpu K           K workers per GPU, K runs sharing it (a single run
                                               leaves most of a large GPU idle; docs/cluster.md)
    reings eval ... --cluster tcp://HOST:8786  an existing scheduler, with workers started by
                                               `reings worker --scheduler tcp://HOST:8786 --device cuda:0`

Each run of the grid (dataset, scene, views, method, seed, settings: one `RunConfig`) is one task.
Every reings worker runs one run at a time (it offers the resource RUN=1, and GPU=1 on a GPU) and
renders on its own device (`REINGS_WORKER_DEVICE` in the worker's environment, which replaces
the run's --device; the device is not part of a run's settings, so a run resumes on any device).
`--gpu-only` makes the tasks ask for GPU=1.

Runs write into the shared --out, as serial `reings eval` does: a finished run (metrics.json) is
never redone; a task whose worker dies is rescheduled by Dask and resumes from the run's own
checkpoints; the per-run lock still keeps two workers (or a serial `reings eval`) off one run on a
shared local filesystem. The table is built when the grid ends (`--table-only` rebuilds it).
`dask.distributed` is imported only here, only when a cluster is asked for.
"""
from __future__ import annotations

import os
import sys
import time

WORKER_DEVICE = "REINGS_WORKER_DEVICE"


class ClusterError(ValueError):
    """A --cluster or worker setting that cannot work (one line)."""


def _distributed():
    try:
        import distributed
    except ImportError as e:
        raise ClusterError("--cluster needs dask.distributed: pip install 'reings[cluster]'") from e
    return distributed


def worker_specs(n: int | None, device: str, runs_per_gpu: int = 1) -> list[dict]:
    """The workers of a local cluster: [{"device", "resources", "env"}], GPUs first, each GPU
    `runs_per_gpu` times (module docstring); PoCL workers get POCL_MAX_PTHREAD_COUNT = their share
    of the spare cores."""
    if runs_per_gpu < 1:
        raise ClusterError(f"--runs-per-gpu needs K >= 1, got {runs_per_gpu}")
    gpus = []
    if device.startswith("cuda"):
        from .backends.opencl.device import list_devices

        gpus = [d for d in list_devices() if d.get("nv_ptx")]
        if not gpus:
            raise ClusterError(f"--cluster local with --device {device}: no NVIDIA GPU found")
        gpus = [f"cuda:{i}" for i in range(len(gpus)) for _ in range(runs_per_gpu)]
    n = (len(gpus) or 1) if n is None else n
    if n < 1:
        raise ClusterError(f"--cluster local:N needs N >= 1, got {n}")
    specs = [{"device": d, "resources": {"RUN": 1, "GPU": 1}, "env": {WORKER_DEVICE: d}} for d in gpus[:n]]
    cpu = n - len(specs)
    if cpu:
        cores = os.cpu_count() or 1
        spare = max(1, cores - len(specs))  # one core stays with each GPU worker's host side
        per = max(1, spare // cpu)
        cpu_dev = "pocl" if device.startswith("cuda") or device in ("", "auto") else device
        specs += [{"device": cpu_dev, "resources": {"RUN": 1},
                   "env": {WORKER_DEVICE: cpu_dev, "POCL_MAX_PTHREAD_COUNT": str(per)}} for _ in range(cpu)]
    return specs


def start_local(n: int | None, device: str, runs_per_gpu: int = 1):
    """A local Dask cluster of one worker process per spec (`worker_specs`), each under a nanny
    (which restarts a worker that dies); returns the connected Client."""
    distributed = _distributed()
    from distributed.deploy.spec import SpecCluster

    specs = worker_specs(n, device, runs_per_gpu)
    workers = {f"reings-{i}-{s['device'].replace(':', '')}": {
        "cls": distributed.Nanny,
        "options": {"nthreads": 1, "resources": s["resources"], "env": s["env"], "silence_logs": 40}}
        for i, s in enumerate(specs)}
    scheduler = {"cls": distributed.Scheduler, "options": {"dashboard_address": ":0"}}
    cluster = SpecCluster(workers=workers, scheduler=scheduler, asynchronous=False, silence_logs=40)
    return distributed.Client(cluster)


def parse_spec(spec: str) -> tuple[str, object]:
    """--cluster `spec` checked before anything is made: ("local", N or None) or ("address", spec)."""
    if spec == "local" or spec.startswith("local:"):
        if spec == "local":
            return "local", None
        try:
            return "local", int(spec.split(":", 1)[1])
        except ValueError:
            raise ClusterError(f"--cluster {spec!r}: expected local:N with an integer N") from None
    if "://" not in spec:
        raise ClusterError(f"--cluster {spec!r}: expected local, local:N or a scheduler address tcp://HOST:PORT")
    return "address", spec


def connect(spec: str, device: str, runs_per_gpu: int = 1):
    """A Client for --cluster `spec`: 'local', 'local:N', or a scheduler address."""
    kind, arg = parse_spec(spec)
    distributed = _distributed()
    if kind == "local":
        return start_local(arg, device, runs_per_gpu)
    try:
        return distributed.Client(arg, timeout="20s")
    except (OSError, TimeoutError) as e:
        raise ClusterError(f"--cluster {spec}: cannot reach the scheduler ({e})") from e


def run_task(cfg) -> dict:
    """One run on the worker that executes it (its device from REINGS_WORKER_DEVICE)."""
    from dataclasses import replace

    from . import pipeline
    from .io.lock import RunLock

    dev = os.environ.get(WORKER_DEVICE)
    if dev:
        cfg = replace(cfg, device=dev)
    rd = cfg.output.out
    if os.path.exists(os.path.join(rd, "metrics.json")):
        return {"out": rd, "status": "done already"}
    lock = RunLock(rd)
    if not lock.acquire():
        # another process holds the run: wait for it (a dead holder's lock is freed by the OS)
        while not lock.acquire():
            time.sleep(2.0)
    try:
        if os.path.exists(os.path.join(rd, "metrics.json")):
            return {"out": rd, "status": "done already"}
        resumed = os.path.isdir(os.path.join(rd, "checkpoints"))
        t = time.perf_counter()
        m = pipeline.run(cfg, quiet=True).metrics
        return {"out": rd, "status": "resumed" if resumed else "ran", "mean": m["mean"],
                "seconds": time.perf_counter() - t, "device": cfg.device, "pid": os.getpid()}
    finally:
        lock.release()


def _n_workers(client) -> int:
    """The scheduler's worker count (distributed >= 2025.4 lists only 5 workers in scheduler_info()
    unless asked for all: n_workers=-1; older versions take no argument)."""
    try:
        info = client.scheduler_info(n_workers=-1)
    except TypeError:
        info = client.scheduler_info()
    return len(info.get("workers", {}))


def run_grid(client, jobs, gpu_only: bool = False, quiet: bool = False, say=print) -> list:
    """Submit every job (ds, scene, cfg) not finished yet; wait with a progress line; returns
    [(out, error)] of the failed runs."""
    distributed = _distributed()
    todo = [(ds, s, cfg) for ds, s, cfg in jobs if not os.path.exists(os.path.join(cfg.output.out, "metrics.json"))]
    nworkers = _n_workers(client)
    say(f"{len(jobs)} run(s), {len(jobs) - len(todo)} finished already; {len(todo)} to do on "
        f"{nworkers} worker(s); dashboard: {client.dashboard_link}")
    res = {"GPU": 1} if gpu_only else {"RUN": 1}
    futs = {}
    for ds, s, cfg in todo:
        key = "reings-run-" + cfg.output.out.replace(os.sep, "_")
        futs[client.submit(run_task, cfg, key=key, resources=res, pure=False)] = cfg
    failed, done, t0 = [], 0, time.perf_counter()
    bar = None
    from .log import progress_enabled

    if progress_enabled(quiet) and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="grid", file=sys.stderr, dynamic_ncols=True)
    for fut in distributed.as_completed(list(futs)):
        cfg = futs[fut]
        try:
            r = fut.result()
            done += 1
            mm = r.get("mean") or {}
            say(f"[{done + len(failed)}/{len(todo)}] {cfg.output.out}: {r['status']}"
                + ("" if not mm else " " + " ".join(f"{k.upper()} {v:.3f}" for k, v in mm.items()))
                + (f" ({r['seconds']:.0f} s on {r['device']})" if "seconds" in r else ""))
        except Exception as e:  # the run raised, or its workers kept dying (KilledWorker)
            failed.append((cfg.output.out, f"{type(e).__name__}: {e}"))
            say(f"[{done + len(failed)}/{len(todo)}] {cfg.output.out}: FAILED: {type(e).__name__}: {e}")
        if bar is not None:
            el = time.perf_counter() - t0
            left = len(todo) - done - len(failed)
            # at most one run per worker runs at a time (each task asks for the whole RUN/GPU resource)
            running = min(left, _n_workers(client) or nworkers)
            bar.set_postfix_str(f"done {done} failed {len(failed)} running {running} "
                                f"ETA {el / max(done + len(failed), 1) * left:.0f} s")
            bar.update(1)
    if bar is not None:
        bar.close()
    return failed


def main_worker(args) -> int:
    """`reings worker`: Dask workers (each under a nanny) bound to one device, `--runs` of them
    (runs sharing the device), until interrupted."""
    import asyncio

    runs = int(getattr(args, "runs", 1))
    if runs < 1:
        raise ClusterError(f"--runs {runs}: needs K >= 1")
    if args.pocl_threads < 0:
        raise ClusterError(f"--pocl-threads {args.pocl_threads}: needs N >= 0 (0: all cores)")
    distributed = _distributed()
    from .backends import get_backend

    get_backend(args.device)  # an unknown device fails here, not in the first task
    res = {"RUN": 1, **({"GPU": 1} if args.device.startswith(("cuda", "opencl")) and args.device != "pocl" else {})}
    env = {WORKER_DEVICE: args.device}
    if args.pocl_threads:
        env["POCL_MAX_PTHREAD_COUNT"] = str(args.pocl_threads)


    async def serve():
        nannies = [distributed.Nanny(args.scheduler, nthreads=1, resources=res, env=env,
                                     name=(f"{args.name}-{i}" if runs > 1 else args.name) if args.name else None)
                   for i in range(runs)]
        try:
            for n in nannies:
                await n
        except (OSError, RuntimeError) as e:  # distributed: "Nanny failed to start." (no scheduler there, ...)
            for n in nannies:
                try:
                    await n.close()
                except Exception:  # noqa: BLE001 - best effort, the start already failed
                    pass
            raise ClusterError(f"--scheduler {args.scheduler}: the worker could not start ({e}); is a scheduler "
                               "listening there?") from None
        print(f"reings worker on {args.device} ({', '.join(f'{k}={v}' for k, v in res.items())}"
              f"{f', {runs} runs at once' if runs > 1 else ''}) -> {args.scheduler}", flush=True)
        try:
            await asyncio.gather(*(n.finished() for n in nannies))
        finally:
            for n in nannies:
                await n.close()

    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        pass
    return 0
