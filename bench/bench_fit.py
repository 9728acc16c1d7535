"""Seconds per training iteration of `reings.fit`: the host engine vs the device-resident engine.

    python bench/bench_fit.py --device cuda                       # H200: both engines, 100k SH3
    python bench/bench_fit.py --device pocl --gaussians 20000 --sh-degree 0 --iterations 100
    python bench/bench_fit.py --device cuda --adam-only           # Adam: one launch, one per group, numpy; per step
    python bench/bench_fit.py --device pocl ... --soft-depth-shared  # the soft depth term on the photometric render
    python bench/bench_fit.py --device pocl ... --view-warp-from 1   # the view_warp term from the first iteration

Case: the built-in procedural scene (`reings.make_procedural_scene`, default 200x150, or
--width/--height), 3 training views with their exact depths as the depth prior, the dngaussian
preset squeezed to --iterations (`reings.train.with_iterations`: hard depth from iteration 1, soft
depth from 1/6 of the run, densification every 10 iterations in the window, penalties), initial
Gaussians back-projected from random pixels of the training views (on the surfaces, like an SfM
init), --gaussians of them.

Per engine: a short warm-up fit (kernel builds), then a timed fit (ms/iteration = wall / its) and,
unless --no-breakdown, a second fit with `profile=` that waits for the queue around each phase and
prints wall ms/iteration per phase and device ms/iteration per kernel stage. One JSON line per
engine goes to --json (appended) for bench/results/.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def surface_init(scene, n, sh_degree, rng):
    """n Gaussians at random pixels of the views, back-projected with the exact depths."""
    from reings.train import gaussians_from_points

    pts, cols = [], []
    per = -(-n // len(scene.images))
    for im, cam, dep in zip(scene.images, scene.cameras, scene.depths):
        h, w = dep.shape
        u = rng.random(per) * w
        v = rng.random(per) * h
        z = dep[v.astype(int), u.astype(int)]
        x_cam = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], 1)
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        pts.append((x_cam - t) @ R)  # R^T (x - t), row vectors
        cols.append(im[v.astype(int), u.astype(int)])
    pts = np.concatenate(pts)[:n].astype(np.float32)
    cols = np.concatenate(cols)[:n].astype(np.float32)
    return gaussians_from_points(pts, cols, sh_degree, rng)


def adam_only(args):
    """Adam over a full set of groups (one photometric step): the kernel (one launch), the kernels
    launched per group (DeviceTrainer.adam_multi False) and numpy on mapped buffers."""
    from reings import densify as D
    from reings.backends import get_backend
    from reings.optim import Adam
    from reings.state import TrainState
    from reings.types import PARAM_NAMES, SH_COUNTS, Gaussians

    rng = np.random.default_rng(0)
    n, k = args.gaussians, SH_COUNTS[args.sh_degree]
    g = Gaussians(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                  rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=n).astype(np.float32),
                  rng.normal(size=(n, k, 3)).astype(np.float32))
    lrs = {name: 1e-3 for name in PARAM_NAMES}
    out = {}
    for loc in ("kernel", "kernel-per-group", "numpy"):  # kernel: one adam_step_multi launch per step
        st = TrainState.from_gaussians(g)
        D.init_stats(st)
        t = get_backend(args.device).trainer([], engine="device", adam=loc.split("-")[0])
        t.adam_multi = loc == "kernel"
        t.upload(st)
        grads = {}
        for f, shp in (("means", (n, 3)), ("quats", (n, 4)), ("log_scales", (n, 3)), ("opacity_logits", (n,)),
                       ("sh", (n, k, 3))):
            a = rng.normal(size=shp).astype(np.float32)
            grads[f] = t.mem.get("gauss", "bench_g_" + f, n, a[0].nbytes)
            t._write(grads[f], a)
        grads["sh_k"] = k
        opt = Adam(st.params, lrs, state=st.adam)
        for _ in range(3):
            t.adam_step(opt, grads, PARAM_NAMES)
        t.finish()
        reps = args.adam_reps
        t0 = time.perf_counter()
        for _ in range(reps):
            t.adam_step(opt, grads, PARAM_NAMES)
        t.finish()
        out[loc] = (time.perf_counter() - t0) / reps * 1e3
        print(f"adam {loc:16s}: {out[loc]:8.3f} ms per step of all 6 groups (N={n}, SH{args.sh_degree}, "
              f"{get_backend(args.device).device_name})", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--engines", default="host,device")
    ap.add_argument("--adam", default="auto", help="device engine's Adam: auto, kernel, numpy")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--gaussians", type=int, default=100_000)
    ap.add_argument("--sh-degree", type=int, default=3)
    ap.add_argument("--width", type=int, default=200)
    ap.add_argument("--height", type=int, default=150)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--no-breakdown", action="store_true")
    ap.add_argument("--adam-only", action="store_true")
    ap.add_argument("--adam-reps", type=int, default=20)
    ap.add_argument("--soft-depth-shared", action="store_true",
                    help="LossConfig.soft_depth_shared: the soft depth term on the photometric pass's render")
    ap.add_argument("--view-warp-from", type=int, default=None,
                    help="the view_warp term (weight 1, docs/binocular.md) from this iteration of the timed fit; "
                         "default off, as in the dngaussian preset")
    ap.add_argument("--json", default=None, help="append one JSON line per engine to this file")
    args = ap.parse_args(argv)

    if args.adam_only:
        adam_only(args)
        return 0

    import reings
    from dataclasses import replace

    from reings.backends import get_backend, set_queue_profiling
    from reings.config import preset
    from reings.train import fit, with_iterations

    if not args.no_breakdown:  # device ms per stage need a profiling queue (its wall is then a profiled queue's)
        set_queue_profiling(True)

    scene = reings.make_procedural_scene(n_views=max(args.views, 3), width=args.width, height=args.height)
    train = scene.subset(list(range(args.views)))
    init = surface_init(train, args.gaussians, args.sh_degree, np.random.default_rng(0))
    cfg = with_iterations(preset("dngaussian"), args.iterations)
    # SH degree steps at 1/6 of the run (3DGS: every 1000 of 6000) so the degree is the full one most
    # of the time, as in a long run
    cfg = replace(cfg, sh_degree=args.sh_degree, loss=replace(cfg.loss, soft_depth_shared=args.soft_depth_shared))
    if args.view_warp_from is not None:
        cfg = replace(cfg, loss=replace(cfg.loss, view_warp_weight=1.0, view_warp_from=args.view_warp_from))
    dev_name = get_backend(args.device).device_name
    print(f"# {dev_name}; {args.views} views {args.width}x{args.height}; {len(init)} initial Gaussians SH{args.sh_degree}; "
          f"dngaussian squeezed to {args.iterations} its"
          + ("" if args.view_warp_from is None else f"; view_warp from iteration {args.view_warp_from}"), flush=True)

    def run(engine, its, profile=None):
        c = with_iterations(cfg, its) if its != args.iterations else cfg
        c = replace(c, sh_degree=args.sh_degree)
        kw = dict(adam=args.adam) if engine == "device" else {}
        t = time.perf_counter()
        r = fit(train, c, device=args.device, init=init, depth_targets=list(train.depths), progress=False,
                log_every=max(its // 5, 1), engine=engine, profile=profile, **kw)
        return r, time.perf_counter() - t

    for engine in args.engines.split(","):
        run(engine, args.warmup)
        r, sec = run(engine, args.iterations)
        ms = sec / args.iterations * 1e3
        rec = {"device": dev_name, "engine": engine, "adam": args.adam if engine == "device" else "numpy",
               "soft_depth_shared": args.soft_depth_shared, "view_warp_from": args.view_warp_from,
               "iterations": args.iterations, "gaussians_init": len(init), "gaussians_final": len(r.gaussians),
               "sh_degree": args.sh_degree, "width": args.width, "height": args.height, "views": args.views,
               "ms_per_iteration": ms, "final_loss": r.history.loss[-1], "final_psnr": r.history.train_psnr[-1]}
        print(f"{engine:6s}: {ms:9.2f} ms/iteration  ({sec:.2f} s, N {len(init)} -> {len(r.gaussians)}, "
              f"loss {r.history.loss[-1]:.4f}, train PSNR {r.history.train_psnr[-1]:.2f})", flush=True)
        if not args.no_breakdown:
            prof = {}
            run(engine, args.iterations, prof)
            dm = prof.pop("device_ms", {})
            its = args.iterations
            rec["phases_ms_per_iteration"] = {k: v / its * 1e3 for k, v in prof.items()}
            rec["device_ms_per_iteration"] = {k: v / its for k, v in dm.items()}
            tot = sum(prof.values()) / its * 1e3
            print(f"        phases (wall, queue finished around each; sum {tot:.2f} ms/it):")
            for k, v in sorted(prof.items(), key=lambda kv: -kv[1]):
                print(f"          {k:16s} {v / its * 1e3:9.3f} ms/it")
            if dm:
                print(f"        device kernel stages (sum {sum(dm.values()) / its:.3f} ms/it):")
                for k, v in sorted(dm.items(), key=lambda kv: -kv[1]):
                    print(f"          {k:20s} {v / its:9.3f} ms/it")
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps(rec) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
