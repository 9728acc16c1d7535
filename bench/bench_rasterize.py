"""Rasterizer alone (kernels/rasterize.cl) on a docs/perf_notes.md §1.7 scene: forward, backward, reduce.

    python bench/bench_rasterize.py [--device pocl] [--scene A] [--runs 40] [--warmup 8]
                                    [--schedule auto|cpu|gpu] [--define RASTER_VEC=16 ...]
    python bench/bench_rasterize.py --define RASTER_ALPHA_CUT=0 --against RASTER_ALPHA_CUT=1   # A/B in one process

Projection and binning come from the float64 reference (`reings.backends.reference`), uploaded
once; only the rasterizer kernels are timed, with OpenCL profiling events (median of --runs after
--warmup), plus wall clock around enqueue+finish. Prints one JSON line per measurement and a table.
Counts: visible Gaussians, intersections, evaluated (pixel, Gaussian) pairs (the reference's count:
pairs up to and including each pixel's stopping Gaussian) and pairs/s of the forward.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from reings.backends import reference as ref  # noqa: E402
from reings.backends.base import V_RECORD  # noqa: E402
from reings.bench_scenes import perf_scene  # noqa: E402


def _upload(h, proj, bins, W: int, H: int):
    """The projection's and binning's arrays as read-only device buffers (by field name), and an
    L1-like cotangent of the image [H, W, 3] (seeded)."""
    import pyopencl as cl

    mf = cl.mem_flags

    def up(a, dt):
        a = np.ascontiguousarray(a, dt)
        return cl.Buffer(h.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a if a.size else np.zeros(1, dt))

    f32, i32 = np.float32, np.int32
    b = {f: up(getattr(proj, f), f32) for f in ("means2d", "conics", "colors", "opacities", "depths")}
    for f in ("tile_ranges", "gid_from_isect", "emit_from_isect", "gid_from_rank", "offset_from_rank"):
        b[f] = up(getattr(bins, f), i32)
    rng = np.random.default_rng(0)
    b["v_rgb"] = up(rng.normal(size=(H, W, 3)) / (H * W), f32)
    b["v_depth"] = up(rng.normal(size=(H, W)) / (H * W), f32)
    return b


def _scene(args):
    """(Gaussians, Camera) of --scene, or of a reings checkpoint (--checkpoint, a fit's
    checkpoints/STAGE.npz) seen from --view of the run's cameras.json (--cameras), opacities
    overridden by --opacity (0.99: the coarse fit's hard depth pass)."""
    if not args.checkpoint:
        return perf_scene(args.scene, n=args.n)
    if args.n is not None:
        raise SystemExit("bench_rasterize: --n is for --scene, not --checkpoint")
    from reings.io.cameras import read_cameras_json
    from reings.types import Gaussians

    z = np.load(args.checkpoint, allow_pickle=False)
    sh = z["param/sh_dc"]
    if "param/sh_rest" in z and z["param/sh_rest"].size:
        sh = np.concatenate([sh, z["param/sh_rest"]], axis=1)
    logits = z["param/opacity_logits"]
    if args.opacity is not None:
        if not 0.0 < args.opacity < 1.0:
            raise SystemExit(f"bench_rasterize: --opacity must be in (0, 1), got {args.opacity}")
        logits = np.full_like(logits, np.log(args.opacity / (1.0 - args.opacity)))
    g = Gaussians(z["param/means"], z["param/quats"], z["param/log_scales"], logits, sh)
    cams = read_cameras_json(args.cameras or str(Path(args.checkpoint).parents[1] / "cameras.json"))
    return g, cams[args.view].camera


def _ms(ev) -> float:
    return (ev.profile.end - ev.profile.start) * 1e-6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="pocl")
    ap.add_argument("--scene", default="A")
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--warmup", type=int, default=8)
    ap.add_argument("--schedule", choices=["auto", "cpu", "gpu"], default="auto")
    ap.add_argument("--define", action="append", default=[], help="extra kernel define NAME=VALUE")
    ap.add_argument("--n", type=int, default=None, help="override the Gaussian count (smoke runs)")
    ap.add_argument("--checkpoint", default=None, help="a reings fit's checkpoints/STAGE.npz instead of --scene")
    ap.add_argument("--cameras", default=None, help="cameras.json of --checkpoint's run (default: the run's)")
    ap.add_argument("--view", type=int, default=0, help="the camera of --cameras (its order)")
    ap.add_argument("--opacity", type=float, default=None, help="every opacity set to this (0.99: the hard pass)")
    ap.add_argument("--cotangent", choices=("rgb", "depth"), default="rgb",
                    help="the backward's cotangent: the image's (photometric) or the depth's (depth passes)")
    ap.add_argument("--no-count", action="store_true", help="skip the reference pair count (slow)")
    ap.add_argument("--against", action="append", default=[], metavar="NAME=VALUE",
                    help="A/B: a second build with these defines (over --define), its runs alternating with "
                         "the first's in this process; prints both medians and the median per-run ratio")
    args = ap.parse_args(argv)
    if args.against:
        return against(args)

    import pyopencl as cl

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.rasterize import Rasterizer

    g, cam = _scene(args)
    W, H = cam.width, cam.height
    t0 = time.perf_counter()
    proj = ref.project_fwd(g, cam)
    bins = ref.bin(proj, W, H)
    t_setup = time.perf_counter() - t0
    n, k, v = len(g), len(bins.gid_from_isect), len(bins.gid_from_rank)

    h = open_device(args.device, profiling=True)  # kernel times from events
    defines = dict(d.split("=", 1) for d in args.define)
    sched = None if args.schedule == "auto" else args.schedule == "cpu"
    r = Rasterizer(h, cpu_schedule=sched, **defines)
    ctx, q = h.context, h.queue
    b = _upload(h, proj, bins, W, H)
    cot = {"v_" + args.cotangent: b["v_" + args.cotangent]}
    grads = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, n * V_RECORD * 4)

    def fwd():
        e0 = r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
        e1 = r.fwd(None, None, None, None, None, n, b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"],
                   k, W, H, (0, 0, 0), prepared=True)
        return e0, e1

    def bwd():
        e2 = r.bwd(b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], k, W, H, **cot)
        e3 = r.reduce(r.v_emit, V_RECORD, b["offset_from_rank"], b["gid_from_rank"], v, grads)
        return e2, e3

    times = {"prep": [], "fwd": [], "bwd": [], "reduce": [], "wall_fwd": [], "wall_fwd_bwd": []}
    for it in range(args.warmup + args.runs):
        q.finish()
        t0 = time.perf_counter()
        e0, e1 = fwd()
        q.finish()
        t1 = time.perf_counter()
        e2, e3 = bwd()
        q.finish()
        t2 = time.perf_counter()
        if it >= args.warmup:
            times["prep"].append(_ms(e0))
            times["fwd"].append(_ms(e1))
            times["bwd"].append(_ms(e2))
            times["reduce"].append(_ms(e3))
            times["wall_fwd"].append((t1 - t0) * 1e3)
            times["wall_fwd_bwd"].append((t2 - t0) * 1e3)
    med = {key: float(np.median(val)) for key, val in times.items()}

    pairs = None
    if not args.no_count:
        pairs = ref.rasterize_fwd(proj, bins, W, H).evaluated_pairs

    base = dict(bench="rasterize", scene=args.scene, device=h.name, driver=h.device.driver_version,
                schedule="cpu" if r.cpu_schedule else "gpu", defines=defines, n=n, visible=v,
                intersections=k, evaluated_pairs=pairs, width=W, height=H, runs=args.runs,
                setup_s=round(t_setup, 2))
    rows = [("prep", med["prep"]), ("fwd", med["fwd"]), ("bwd", med["bwd"]), ("reduce", med["reduce"]),
            ("fwd total (prep+fwd)", med["prep"] + med["fwd"]),
            ("fwd+bwd total", med["prep"] + med["fwd"] + med["bwd"] + med["reduce"]),
            ("wall fwd", med["wall_fwd"]), ("wall fwd+bwd", med["wall_fwd_bwd"])]
    for name, ms in rows:
        rec = dict(base, stage=name, median_ms=round(ms, 4))
        if pairs and name in ("fwd", "bwd"):
            rec["pairs_per_s"] = pairs / (ms * 1e-3)
        print(json.dumps(rec))
    print(f"\n{h.name} | scene {args.scene} {W}x{H} | N={n} visible={v} K={k} pairs={pairs} "
          f"| schedule={'cpu' if r.cpu_schedule else 'gpu'} {defines or ''}")
    for name, ms in rows:
        extra = f"  {pairs / (ms * 1e-3) / 1e6:8.1f} M pairs/s" if pairs and name in ("fwd", "bwd") else ""
        print(f"  {name:22s} {ms:9.3f} ms{extra}")


def against(args):
    """Alternate two builds run by run (A, B, B, A, ...) so that a machine's drift (other tenants, clock)
    falls on both: the per-run ratio B / A is the measurement. Times rasterize_fwd and rasterize_bwd only
    and isect_reduce (not rasterize_prep); a schedule switch (REINGS_CPU_SCHEDULE) is --schedule's, not a define's."""

    from reings.backends.opencl.device import open_device
    from reings.backends.opencl.rasterize import Rasterizer

    if any(d.split("=", 1)[0] == "REINGS_CPU_SCHEDULE" for d in args.against + args.define):
        raise SystemExit("bench_rasterize: the schedule is --schedule's, not a define's")
    g, cam = _scene(args)
    W, H = cam.width, cam.height
    proj = ref.project_fwd(g, cam)
    bins = ref.bin(proj, W, H)
    n, k, v = len(g), len(bins.gid_from_isect), len(bins.gid_from_rank)
    h = open_device(args.device, profiling=True)
    sched = None if args.schedule == "auto" else args.schedule == "cpu"
    da = dict(d.split("=", 1) for d in args.define)
    db = dict(da, **dict(d.split("=", 1) for d in args.against))
    rs = [Rasterizer(h, cpu_schedule=sched, **da), Rasterizer(h, cpu_schedule=sched, **db)]
    q = h.queue
    b = _upload(h, proj, bins, W, H)
    cot = {"v_" + args.cotangent: b["v_" + args.cotangent]}
    import pyopencl as cl

    grads = cl.Buffer(h.context, cl.mem_flags.READ_WRITE, max(n, 1) * V_RECORD * 4)
    times = [{"fwd": [], "bwd": [], "reduce": []} for _ in rs]
    for it in range(args.warmup + args.runs):
        for j in ((0, 1) if it % 2 == 0 else (1, 0)):  # A, B then B, A: no build always runs first
            r = rs[j]
            r.prep(b["means2d"], b["conics"], b["colors"], b["opacities"], b["depths"], n)
            e1 = r.fwd(None, None, None, None, None, n, b["tile_ranges"], b["gid_from_isect"],
                       b["emit_from_isect"], k, W, H, (0, 0, 0), prepared=True)
            e2 = r.bwd(b["tile_ranges"], b["gid_from_isect"], b["emit_from_isect"], k, W, H, **cot)
            e3 = r.reduce(r.v_emit, V_RECORD, b["offset_from_rank"], b["gid_from_rank"], v, grads)
            q.finish()
            if it >= args.warmup:
                times[j]["fwd"].append(_ms(e1))
                times[j]["bwd"].append(_ms(e2))
                times[j]["reduce"].append(_ms(e3))
    print(f"{h.name} | scene {args.scene} {W}x{H} | N={n} K={k} | A {da or '{}'} | B {db}")
    for stage in ("fwd", "bwd", "reduce"):
        a, bb = np.array(times[0][stage]), np.array(times[1][stage])
        ratio = bb / a
        print(json.dumps(dict(bench="rasterize_ab", scene=args.scene, stage=stage, a_defines=da, b_defines=db,
                              a_median_ms=round(float(np.median(a)), 3), b_median_ms=round(float(np.median(bb)), 3),
                              ratio_median=round(float(np.median(ratio)), 4),
                              ratio_q25_q75=[round(float(x), 4) for x in np.percentile(ratio, [25, 75])])))


if __name__ == "__main__":
    main()
