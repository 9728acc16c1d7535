"""The host's share of a training iteration of the device engine (issue 15: is a GPU run host-bound?).

    python bench/bench_host.py --device pocl --mode wall      # ms/iteration, steady state
    python bench/bench_host.py --device pocl --mode stubbed   # the same loop, every kernel launch a no-op
    python bench/bench_host.py --device pocl --mode calls     # OpenCL commands and host syncs per iteration
    python bench/bench_host.py --device pocl --mode cprofile  # the host's top costs per iteration
    python bench/bench_host.py --device pocl --mode pycalls   # Python / C-level calls per iteration, launches stubbed
    python bench/bench_host.py --device pocl --mode wall --save /tmp/p.npz   # final state, for a bitcheck
    REINGS_BIN=async python bench/bench_host.py --device pocl --mode calls  # the sync-free binning
    REINGS_DEPTH_ORDER=sort python bench/bench_host.py --device pocl --mode calls  # every forward sorts

Case: the built-in procedural scene (--width x --height, default 504x378 as LLFF at the paper's
resolution), 3 training views with their exact depths as the depth prior, --gaussians initial
Gaussians back-projected from the views (bench_fit.surface_init), SH degree --sh-degree active from
iteration 1. The recipe is the fine ReInGS fit's (`pipeline.soft_depth_recipe`, LLFF family) with
every pass of a late iteration of `reings eval --preset paper` switched on from iteration 1: the hard
depth pass too (the coarse fit's), the soft depth pass, the photometric pass (L1 + SSIM) with the
view_warp term (a kept virtual render), DropGaussian (gamma 0.2), the penalties, the depth_smooth
term; `log_every` 10 as in `reings eval`. Densification is off (its cost is a download, host
surgery and an upload every 100 iterations: not a per-iteration cost), as are checkpoints.

ms/iteration is steady state: from the first logging iteration to the last (History.seconds), so
kernel builds, the upload and the first iterations are left out. A warm-up fit of --warmup
iterations runs first in the same process (kernel builds; with --mode stubbed it also leaves the
binning's (V, K) words of a real forward in the device buffers, so the stubbed loop takes the
host path of a real one). One JSON line per run goes to --json (appended), with the backend's
binning mode (`bin_mode`, from REINGS_BIN: docs/perf_notes.md §8) and the forwards binned per mode,
its depth order mode (`depth_order`, from REINGS_DEPTH_ORDER: docs/perf_notes.md §9) and the
forwards of the measured fit that sorted / shared a depth order (`depth_sorts`).
"""
from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import sys
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def recipe(iterations: int, sh_degree: int, drop: float, view_warp: bool):
    """The fine fit's recipe with every pass on from iteration 1 (module docstring)."""
    from reings.pipeline import soft_depth_recipe

    c = soft_depth_recipe(6000, sh_degree, "llff")
    L = replace(c.loss, hard_depth=True, hard_depth_from=1, soft_depth_from=1, depth_smooth_from=1,
                drop_gamma=drop, view_warp_weight=1.0 if view_warp else 0.0, view_warp_from=1,
                view_warp_baseline=0.05)
    return replace(c, iterations=iterations, sh_degree=sh_degree, sh_degree_interval=1, loss=L,
                   densify=replace(c.densify, densify_from=iterations + 1, densify_until=iterations + 1),
                   optim=replace(c.optim, position_lr_start=0, position_lr_max_steps=iterations))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--mode", default="wall", choices=("wall", "stubbed", "calls", "cprofile", "pycalls"))
    ap.add_argument("--iterations", type=int, default=41)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--gaussians", type=int, default=30_000)
    ap.add_argument("--sh-degree", type=int, default=1)
    ap.add_argument("--width", type=int, default=504)
    ap.add_argument("--height", type=int, default=378)
    ap.add_argument("--log-every", type=int, default=10)
    ap.add_argument("--drop", type=float, default=0.2, help="DropGaussian's gamma (0: off)")
    ap.add_argument("--no-view-warp", action="store_true")
    ap.add_argument("--top", type=int, default=35, help="cprofile: rows printed")
    ap.add_argument("--prof-out", default=None, help="cprofile: write the table here too")
    ap.add_argument("--save", default=None, help="np.savez the final state and history here (bitchecks)")
    ap.add_argument("--label", default="", help="a free label for the JSON line")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    import reings
    from bench_fit import surface_init
    from reings.backends import get_backend
    from reings.backends.opencl.harness import ClCalls, launches_stubbed
    from reings.train import fit

    scene = reings.make_procedural_scene(n_views=3, width=args.width, height=args.height)
    init = surface_init(scene, args.gaussians, args.sh_degree, np.random.default_rng(0))
    be = get_backend(args.device)

    def run(its, profile=None):
        cfg = recipe(its, args.sh_degree, args.drop, not args.no_view_warp)
        return fit(scene, cfg, device=args.device, init=init, depth_targets=list(scene.depths),
                   log_every=args.log_every, engine="device", profile=profile)

    run(args.warmup)
    its = args.iterations
    sorts0 = dict(be.depth_sorts)
    calls = prof = per = None
    t = time.perf_counter()
    if args.mode == "wall":
        r = run(its)
    elif args.mode == "stubbed":
        with launches_stubbed():
            r = run(its)
    elif args.mode == "calls":
        with ClCalls() as calls:
            r = run(its)
    elif args.mode == "pycalls":  # sys.setprofile's call events of a fit of its and of 2 its - 1 iterations: the
        counts = []               # difference per iteration leaves the fit's own setup out (docs/perf_notes.md §25)
        with launches_stubbed():
            for n_its in (its, 2 * its - 1):
                c = {"call": 0, "c_call": 0}

                def count(frame, event, arg, c=c):
                    if event in c:
                        c[event] += 1

                sys.setprofile(count)
                try:
                    r = run(n_its)
                finally:
                    sys.setprofile(None)
                counts.append(c)
        per = {k: (counts[1][k] - counts[0][k]) / (its - 1) for k in ("call", "c_call")}
        print(f"pycalls  {args.label}: {per['call']:.1f} Python and {per['c_call']:.1f} C-level calls per iteration "
              f"(launches stubbed)", flush=True)
    else:
        prof = cProfile.Profile()
        prof.enable()
        r = run(its)
        prof.disable()
    wall = time.perf_counter() - t
    h = r.history
    if len(h.iteration) < 3:
        raise SystemExit("bench_host: --log-every must leave at least 3 logging iterations in --iterations")
    steady = (h.seconds[-1] - h.seconds[0]) / (h.iteration[-1] - h.iteration[0]) * 1e3
    rec = dict(label=args.label, mode=args.mode, source=os.path.dirname(reings.__file__), device=be.device_name,
               gaussians=args.gaussians,
               sh_degree=args.sh_degree, width=args.width, height=args.height, iterations=its,
               log_every=args.log_every, drop=args.drop, view_warp=not args.no_view_warp,
               ms_per_iteration=steady, fit_seconds=wall, final_loss=h.loss[-1], final_psnr=h.train_psnr[-1],
               bin_mode=be.bin_mode, binned=dict(be.binned), depth_order=be.depth_order,
               depth_sorts={k: v - sorts0[k] for k, v in be.depth_sorts.items()})
    print(f"{args.mode:8s} {args.label}: {steady:8.2f} ms/iteration (steady, its {h.iteration[0]}..{h.iteration[-1]}); "
          f"fit {wall:.2f} s; loss {h.loss[-1]:.6f} psnr {h.train_psnr[-1]:.4f}; "
          f"binning {be.bin_mode} {be.binned}; depth order {be.depth_order} {rec['depth_sorts']}", flush=True)
    if per is not None:
        rec["python_calls_per_iteration"] = per
    if calls is not None:
        rec["calls_per_iteration"] = calls.as_dict(per=its)
        print("  per iteration: " + ", ".join(f"{k} {v:.1f}" for k, v in rec["calls_per_iteration"].items() if v),
              flush=True)
    if prof is not None:
        for key in ("tottime", "cumulative"):
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats(key).print_stats(args.top)
            text = f"# cProfile of a {its}-iteration fit ({args.label}), sorted by {key}\n" + s.getvalue()
            print(text)
            if args.prof_out:
                with open(args.prof_out, "a") as f:
                    f.write(text)
    if args.save:
        st = r.state
        np.savez(args.save, **st.to_arrays(), loss=np.array(h.loss), psnr=np.array(h.train_psnr))
    if args.json:
        with open(args.json, "a") as f:
            f.write(json.dumps(rec) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
