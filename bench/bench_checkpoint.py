"""The cost of one checkpoint of a fit (issue 15: where do a GPU run's seconds outside the iterations go?).

    python bench/bench_checkpoint.py --device pocl --gaussians 20000 57000 --sh-degree 1
    python bench/bench_checkpoint.py --dir /dev/shm ...     # the same, on a memory filesystem

A checkpoint (`_Bookkeeping.end` in reings/train.py) is `Trainer.download(state)` (parameters, both
Adam moments and the densification statistics to the host) followed by `_save_checkpoint`
(`TrainState.to_arrays`, the history as JSON, `np.savez` through `atomic_write`: a temporary file,
fsync, rename). This script times each part on a TrainState of --gaussians rows at --sh-degree with
random values and the device trainer of --device holding it, and a history the size of the end of a
6000-iteration `reings eval --preset paper` fit (log_every 10: 600 entries per series, 15 probes, 30
densification records, the view_warp series). --repeats times each part; the median is reported.
One JSON line per size goes to --json (appended).
"""
from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def fake_history(iterations: int = 6000, log_every: int = 10):
    """A History the size of one paper fit's at its end (module docstring)."""
    from reings.train import History

    rng = np.random.default_rng(0)
    its = list(range(log_every, iterations + 1, log_every))
    h = History(iteration=its, loss=[float(x) for x in rng.random(len(its))],
                train_psnr=[float(20 + x) for x in rng.random(len(its))],
                n_gaussians=[int(20000 + i) for i in range(len(its))],
                seconds=[float(i * 0.01) for i in range(len(its))])
    h.densify = [(i, {"clone": 100, "split": 200, "prune": 50, "total": 20000}) for i in range(500, 3500, 100)]
    h.eval = [(i, i * 0.01, {"psnr": 20.0 + i / 1e4, "eval_seconds": 0.03}) for i in range(400, 6001, 400)]
    h.view_warp = [(i, 0.01, 0.9) for i in its]
    return h


def med(f, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--gaussians", type=int, nargs="+", default=[20_000, 57_000])
    ap.add_argument("--sh-degree", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--dir", default=None, help="folder the checkpoint is written to (default: a temp folder)")
    ap.add_argument("--label", default="")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    import reings
    from reings.backends import get_backend
    from reings.state import TrainState
    from reings.train import _save_checkpoint
    from reings.types import SH_COUNTS, STAT_DTYPES, Gaussians

    be = get_backend(args.device)
    scene = reings.make_procedural_scene(n_views=3, width=504, height=378)
    hist = fake_history()
    rng = np.random.default_rng(1)
    tmpdir = tempfile.mkdtemp(prefix="ckbench-", dir=args.dir)
    for n in args.gaussians:
        k = SH_COUNTS[args.sh_degree]
        g = Gaussians(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                      rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=n).astype(np.float32),
                      rng.normal(size=(n, k, 3)).astype(np.float32))
        st = TrainState.from_gaussians(g)
        for d in (st.adam.exp_avg, st.adam.exp_avg_sq):
            for key in d:
                d[key] = rng.random(d[key].shape).astype(np.float32)
        st.stats = {k: np.zeros(n, t) for k, t in STAT_DTYPES.items()}
        tr = be.trainer(list(scene.images), engine="device")
        tr.upload(st)
        tr.finish()
        path = os.path.join(tmpdir, "ck.npz")
        r = {"label": args.label, "device": be.device_name, "gaussians": n, "sh_degree": args.sh_degree,
             "dir": tmpdir, "repeats": args.repeats}
        r["download_s"] = med(lambda: tr.download(st), args.repeats)
        r["download_params_s"] = med(lambda: tr.download(st, params_only=True), args.repeats)
        r["to_arrays_s"] = med(st.to_arrays, args.repeats)
        r["history_json_s"] = med(lambda: json.dumps(hist.to_dict()), args.repeats)
        r["history_json_bytes"] = len(json.dumps(hist.to_dict()))
        r["savez_memory_s"] = med(lambda: np.savez(io.BytesIO(), **st.to_arrays()), args.repeats)
        r["save_checkpoint_s"] = med(lambda: _save_checkpoint(path, st, rng, hist, {"desc": "bench"}), args.repeats)
        r["checkpoint_bytes"] = os.path.getsize(path)
        r["checkpoint_s"] = r["download_s"] + r["save_checkpoint_s"]
        print(f"{n:6d} Gaussians SH{args.sh_degree}: download {r['download_s'] * 1e3:7.1f} ms "
              f"(params only {r['download_params_s'] * 1e3:.1f}), save {r['save_checkpoint_s'] * 1e3:7.1f} ms "
              f"(savez to memory {r['savez_memory_s'] * 1e3:.1f}, history json {r['history_json_s'] * 1e3:.1f} ms, "
              f"{r['history_json_bytes'] / 1e3:.0f} kB), file {r['checkpoint_bytes'] / 2**20:.1f} MiB; "
              f"checkpoint {r['checkpoint_s'] * 1e3:.1f} ms", flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps(r) + "\n")
        os.unlink(path)
    os.rmdir(tmpdir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
