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

On a cluster of GPU and CPU (PoCL) workers (and without --gpu-only) the runs are not all submitted
at once: the driver keeps them in a queue (`GridSchedule`), keeps two runs in flight per GPU slot,
and gives an idle CPU worker a run only when that run should end there before the GPUs would
clear the rest of the queue (`admit_to_cpu`, docs/cluster.md). A cluster of one kind submits
every run at once, as before.

Runs write into the shared --out, as serial `reings eval` does: a finished run (metrics.json) is
never redone; a task whose worker dies is rescheduled by Dask and resumes from the run's own
checkpoints; the per-run lock still keeps two workers (or a serial `reings eval`) off one run on a
shared local filesystem. The table is built when the grid ends (`--table-only` rebuilds it).
`dask.distributed` is imported only here, only when a cluster is asked for.
"""
from __future__ import annotations

import os
import statistics
import sys
import time

WORKER_DEVICE = "REINGS_WORKER_DEVICE"

# The slowdown of a CPU (PoCL) run against the same run on a GPU, used until a CPU run of the grid
# has finished: on one H100 with 16 Xeon cores a quick LLFF run took 5-28 s on the GPU and
# 109-262 s on PoCL (3 workers sharing 15 cores), 10-27x; a full-schedule run ~90 s against
# ~40 min (docs/results.md section 11).
R0 = 20.0
# Runs in flight per GPU slot: one running and one waiting, so a GPU never idles on the driver.
GPU_AHEAD = 2


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
    specs = [{"device": d, "resources": {"RUN": 1, "GPU": 1}, "env": {WORKER_DEVICE: d, **_bin_budget(runs_per_gpu)}}
             for d in gpus[:n]]
    cpu = n - len(specs)
    if cpu:
        cores = os.cpu_count() or 1
        spare = max(1, cores - len(specs))  # one core stays with each GPU worker's host side
        per = max(1, spare // cpu)
        cpu_dev = "pocl" if device.startswith("cuda") or device in ("", "auto") else device
        specs += [{"device": cpu_dev, "resources": {"RUN": 1},
                   "env": {WORKER_DEVICE: cpu_dev, "POCL_MAX_PTHREAD_COUNT": str(per)}} for _ in range(cpu)]
    return specs


def _bin_budget(runs_per_gpu: int) -> dict:
    """The env of a GPU worker sharing its GPU with runs_per_gpu - 1 others: each gets that share
    of the sync-free binning's memory budget (REINGS_BIN_BUDGET, docs/perf_notes.md §8), unless
    the variable is set already."""
    from .backends.opencl.bin_counts import BIN_BUDGET_ENV, bin_budget_setting

    if runs_per_gpu <= 1 or os.environ.get(BIN_BUDGET_ENV):
        return {}
    return {BIN_BUDGET_ENV: repr(bin_budget_setting(None) / runs_per_gpu)}


def _worker_environ():
    """Dask config for making reings workers' nannies: without Dask's MALLOC_TRIM_THRESHOLD_=65536.
    Setting any glibc malloc threshold turns off glibc's dynamic mmap threshold, so every large
    numpy temporary is mmap'd and page-faulted afresh: on an H100 machine the host side of a run
    (metrics, probes, densification) took 1.6-1.8x as long in a worker as in a serial `reings eval`
    (docs/results.md §15); Dask's thread limits (OMP/MKL/OPENBLAS = 1) stay."""
    import dask

    return dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None})


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
    with _worker_environ():
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
                "seconds": time.perf_counter() - t, "device": cfg.device, "pid": os.getpid(),
                "worker": _worker_address()}
    finally:
        lock.release()


def _worker_address() -> str | None:
    """The address of the Dask worker running this task (None outside one)."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return None


def gpu_estimate(group, gpu_done: dict) -> float | None:
    """The expected GPU seconds of a run of `group` (its method): the mean of the finished GPU runs
    of that group ({group: [seconds]}), else the mean of all of them; None before any."""
    own = gpu_done.get(group)
    if own:
        return sum(own) / len(own)
    every = [t for ts in gpu_done.values() for t in ts]
    return sum(every) / len(every) if every else None


def slowdown(cpu_done: list, gpu_done: dict, r0: float = R0) -> float:
    """R, a CPU run's seconds over a GPU run's: the median of seconds / gpu_estimate(group) over the
    finished CPU runs [(group, seconds)]; `r0` before any (or before any GPU run)."""
    ratios = [t / e for g, t in cpu_done if (e := gpu_estimate(g, gpu_done))]
    return statistics.median(ratios) if ratios else r0


def admit_to_cpu(queued_costs, running_gpu_left: float, n_gpu: int, ratio: float) -> int | None:
    """Which queued run an idle CPU worker should take, or None (list scheduling).

    queued_costs: the expected GPU seconds of each queued run; running_gpu_left: the expected GPU
    seconds still to go of the runs already on the GPU slots; n_gpu: GPU slots; ratio: R. The GPU
    slots alone clear the queue in backlog = (sum(queued_costs) + running_gpu_left) / n_gpu.
    The cheapest run c goes to the CPU iff R * c < backlog - c / n_gpu: it ends there before the
    GPUs would have cleared the rest without it (the test is monotone in c, so if the cheapest
    fails, every run does). Ties: the first in the queue."""
    if n_gpu < 1:
        raise ValueError(f"admit_to_cpu: n_gpu = {n_gpu}, needs >= 1")
    if not queued_costs:
        return None
    k = min(range(len(queued_costs)), key=queued_costs.__getitem__)
    c = queued_costs[k]
    backlog = (sum(queued_costs) + running_gpu_left) / n_gpu
    return k if ratio * c < backlog - c / n_gpu else None


class GridSchedule:
    """The driver's side of a grid on a mixed GPU + CPU cluster, with no Dask in it (the Dask loop
    of `run_grid` and the tests' simulation drive it alike).

    Runs are 0..n-1 in grid order, `groups[i]` the group whose GPU times estimate run i's (its
    method). The queue holds the runs not yet submitted. `feed_gpu` tops the GPU slots up to
    GPU_AHEAD runs each, a run of each group not yet measured first, then from the front of the
    queue; `admit` hands idle CPU workers runs by `admit_to_cpu` once every queued group has a
    finished GPU run; `finished` records an ended run. Which GPU run runs and which waits is
    modelled first in, first out (a run starts when it is submitted to a free slot, or when a GPU
    run ends): it only feeds the estimate of the GPU work still to go."""

    def __init__(self, groups, r0: float = R0):
        self.groups = list(groups)
        self.r0 = r0
        self.queue = list(range(len(self.groups)))
        self.gpu: dict[int, float | None] = {}  # run on a GPU slot -> its start (None: waiting), oldest first
        self.cpu: dict[int, str] = {}  # run on a CPU worker -> the worker
        self.gpu_done: dict[str, list[float]] = {}  # group -> seconds of the finished GPU runs
        self.cpu_done: list[tuple[str, float]] = []  # (group, seconds) of the finished CPU runs

    def ratio(self) -> float:
        return slowdown(self.cpu_done, self.gpu_done, self.r0)

    def running(self) -> int:
        """Runs executing now (the GPU model's started runs and the CPU runs)."""
        return sum(t is not None for t in self.gpu.values()) + len(self.cpu)

    def gpu_left(self, now: float) -> float:
        """Expected GPU seconds still to go of the runs on the GPU slots."""
        left = 0.0
        for i, start in self.gpu.items():
            e = gpu_estimate(self.groups[i], self.gpu_done) or 0.0
            left += e if start is None else max(0.0, e - (now - start))
        return left

    def _start_waiting(self, n_gpu: int, now: float) -> None:
        free = n_gpu - sum(t is not None for t in self.gpu.values())
        for i in [i for i, t in self.gpu.items() if t is None][:max(0, free)]:
            self.gpu[i] = now

    def _unmeasured(self) -> set:
        """The groups with a run queued and no finished GPU run yet."""
        return {self.groups[i] for i in self.queue} - set(self.gpu_done)

    def feed_gpu(self, n_gpu: int, now: float) -> list[int]:
        """The queued runs to submit to the GPU slots now: first the first run of each group with
        no GPU run finished or under way (so every group is soon measured), then the front of the
        queue."""
        new = []
        while self.queue and len(self.gpu) < GPU_AHEAD * n_gpu:
            seen = set(self.gpu_done) | {self.groups[j] for j in self.gpu}
            k = next((k for k, i in enumerate(self.queue) if self.groups[i] not in seen), 0)
            i = self.queue.pop(k)
            self.gpu[i] = None
            new.append(i)
        self._start_waiting(n_gpu, now)
        return new

    def admit(self, idle_cpu, n_gpu: int, now: float) -> list[tuple[int, str, float, float]]:
        """[(run, worker, expected CPU seconds, GPU backlog seconds)] for the idle CPU worker slots
        `idle_cpu` (a worker once per free slot). None while a queued run's group has no finished
        GPU run: costed at the other groups' mean, a cheap group would swell the backlog and
        let a dear run onto the CPU (`feed_gpu` measures every group first)."""
        out = []
        if not self.gpu_done or self._unmeasured():
            return out
        r = self.ratio()
        for w in idle_cpu:
            costs = [gpu_estimate(self.groups[i], self.gpu_done) for i in self.queue]
            left = self.gpu_left(now)
            k = admit_to_cpu(costs, left, n_gpu, r)
            if k is None:
                break
            i = self.queue.pop(k)
            self.cpu[i] = w
            out.append((i, w, r * costs[k], (sum(costs) + left) / n_gpu))
        return out

    def finished(self, i: int, now: float, seconds: float | None = None, on_gpu: bool | None = None,
                 n_gpu: int = 1) -> None:
        """Run i ended at `now`; `seconds`: its run time where it is a whole run's (not for a failed,
        resumed or already finished run), `on_gpu`: whether a GPU worker ran it (by default, where
        it was submitted; Dask may move a CPU run to a GPU worker when its worker dies)."""
        submitted_gpu = i in self.gpu
        self.gpu.pop(i, None)
        self.cpu.pop(i, None)
        if seconds is not None:
            if submitted_gpu if on_gpu is None else on_gpu:
                self.gpu_done.setdefault(self.groups[i], []).append(float(seconds))
            else:
                self.cpu_done.append((self.groups[i], float(seconds)))
        self._start_waiting(n_gpu, now)


def _workers(client) -> dict:
    """The scheduler's workers {address: info} (distributed >= 2025.4 lists only 5 workers in
    scheduler_info() unless asked for all: n_workers=-1; older versions take no argument)."""
    try:
        info = client.scheduler_info(n_workers=-1)
    except TypeError:
        info = client.scheduler_info()
    return info.get("workers", {})


def _n_workers(client) -> int:
    return len(_workers(client))


def _is_gpu(worker_info: dict) -> bool:
    return (worker_info.get("resources") or {}).get("GPU", 0) >= 1


def _slots(workers: dict) -> tuple[int, dict]:
    """(GPU slots, {CPU worker: slots}): a worker offering GPU runs min(threads, GPU) GPU=1 tasks
    at once; one offering RUN but no GPU is a CPU worker of min(threads, RUN) slots."""
    n_gpu, cpu = 0, {}
    for addr, w in workers.items():
        res, nt = w.get("resources") or {}, int(w.get("nthreads") or 1)
        if _is_gpu(w):
            n_gpu += min(nt, int(res["GPU"]))
        elif res.get("RUN", 0) >= 1:
            cpu[addr] = min(nt, int(res["RUN"]))
    return n_gpu, cpu


def run_grid(client, jobs, gpu_only: bool = False, quiet: bool = False, say=print) -> list:
    """Run every job (ds, scene, cfg) not finished yet; wait with a progress line; returns
    [(out, error)] of the failed runs. A cluster of GPU and CPU workers (without `gpu_only`) gets
    its runs through `GridSchedule`; any other gets them all at once, each asking for RUN=1 (GPU=1
    with `gpu_only`)."""
    distributed = _distributed()
    todo = [(ds, s, cfg) for ds, s, cfg in jobs if not os.path.exists(os.path.join(cfg.output.out, "metrics.json"))]
    workers = _workers(client)
    nworkers = len(workers)
    say(f"{len(jobs)} run(s), {len(jobs) - len(todo)} finished already; {len(todo)} to do on "
        f"{nworkers} worker(s); dashboard: {client.dashboard_link}")
    n_gpu, cpu_slots = _slots(workers)
    mixed = bool(todo) and not gpu_only and n_gpu > 0 and bool(cpu_slots)
    failed, done, t0 = [], 0, time.perf_counter()
    futs = {}  # future -> index into todo

    def submit(i, **kw):
        cfg = todo[i][2]
        key = "reings-run-" + cfg.output.out.replace(os.sep, "_")
        fut = client.submit(run_task, cfg, key=key, pure=False, **kw)
        futs[fut] = i
        return fut

    if not mixed:
        res = {"GPU": 1} if gpu_only else {"RUN": 1}
        ac = distributed.as_completed([submit(i, resources=res) for i in range(len(todo))])
        sched = None
    else:
        say(f"{n_gpu} GPU slot(s), {sum(cpu_slots.values())} CPU slot(s): a CPU worker takes a run only "
            f"when it should end there before the GPUs clear the queue (CPU/GPU slowdown {R0:.0f}x until "
            "measured; docs/cluster.md)")
        sched = GridSchedule([getattr(cfg, "method", "") for _, _, cfg in todo])
        ac = distributed.as_completed()
        on_gpu_worker = {a: _is_gpu(w) for a, w in workers.items()}  # every worker seen, dead ones too

        def top_up(now):
            nonlocal n_gpu
            ws = _workers(client)
            g, cpu = _slots(ws)
            n_gpu = g or n_gpu  # a lone GPU worker restarting by its nanny: keep its slots
            on_gpu_worker.update({a: _is_gpu(w) for a, w in ws.items()})
            for i in sched.feed_gpu(n_gpu, now):
                ac.add(submit(i, resources={"GPU": 1}))
            busy = client.processing(list(cpu)) if cpu else {}
            mine = {}
            for w in sched.cpu.values():
                mine[w] = mine.get(w, 0) + 1
            idle = [a for a, n in cpu.items() for _ in range(n - max(len(busy.get(a, ())), mine.get(a, 0)))]
            for i, w, cpu_s, backlog in sched.admit(idle, n_gpu, now):
                # allow_other_workers: a restarted worker comes back at a new address, so a run
                # held to the dead one would wait for ever; with it Dask reruns it on any worker
                ac.add(submit(i, resources={"RUN": 1}, workers=[w], allow_other_workers=True))
                say(f"  {todo[i][2].output.out} -> CPU worker {w} (~{cpu_s:.0f} s there; the GPUs "
                    f"have ~{backlog:.0f} s of runs queued)")

        top_up(time.perf_counter())
    bar = None
    from .log import progress_enabled

    if progress_enabled(quiet) and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="grid", file=sys.stderr, dynamic_ncols=True)
    for fut in ac:
        i = futs.pop(fut)
        cfg = todo[i][2]
        r = None
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
        left = len(todo) - done - len(failed)
        if sched is not None:
            now = time.perf_counter()
            whole = r is not None and r.get("status") == "ran" and "seconds" in r
            sched.finished(i, now, r["seconds"] if whole else None,
                           on_gpu_worker.get(r.get("worker")) if whole else None, n_gpu)
            top_up(now)
            running = sched.running()
        if bar is not None:
            el = time.perf_counter() - t0
            if sched is None:
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
        with _worker_environ():
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
