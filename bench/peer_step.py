"""Training step, ours vs gsplat's, in ONE process on the same scene arrays (the GPU fast-path headline).

    python bench/peer_step.py --device cuda [--scenes A,B,C] [--sh 0,3] [--json OUT.jsonl]
    python bench/peer_step.py --device pocl --scenes A --sh 0 --warmup 1 --repeats 3 --n 20000
    python bench/peer_step.py --device pocl --overhead          # host overhead per step, tiny image

Per scene (reings/bench_scenes.py perf scenes, 504x378) x SH degree, the arrays are built once, then
  * ours: `DeviceTrainer.step_l1` (reings.bench.bench_train_step): forward from the device-resident
    parameters, L1 = mean|rgb - target| on the device (no SSIM pass), backward, Adam kernel over all
    groups (lr 1e-3, eps 1e-15), no loss read: the only host read is the binning's (V, K). Median wall
    clock per step with a queue.finish() after each, after --warmup steps; then a profiled run for
    the device time per stage (sum) and the device span (first kernel start to last kernel end);
    OpenCL launches and host syncs per step;
  * gsplat (if torch + CUDA + gsplat import): bench/peer_gsplat.py's step (forward, L1 mean abs vs
    the same target, backward, torch fused Adam lr 1e-3 eps 1e-15), timed with its `_time_cuda`
    (median of CUDA-event and of wall-clock-with-synchronize timings after warm-ups);
  * accuracy: our image (device engine forward) vs the float64 reference (device "reference") on the
    centred --ref-crop window (0: full image; the full 100k image takes the reference minutes), and
    vs gsplat's image of the same parameters (mean and max abs over the full image; the conventions
    agree: pinhole, pixel centres at +0.5, black background, 3-sigma-style extent differences show
    up as a small max).
Ratio = ours wall / gsplat wall (< 1: we are faster). With --rounds R > 1 the two sides alternate R times per
configuration (each round re-creates both steps, warmed up and timed as the first): the host's
drift between the two measurements (up to ~1 ms on an H100 host, docs/results.md §31) then hits both sides;
the row reports the median of the per-round ratios, the rounds' walls and ratios, and round 1's ratio.

--overhead: the host side alone, on a tiny image (--overhead-size, default 32x32, --overhead-n
Gaussians of scene A), where kernel time is negligible: us per step (wall, with a finish per step),
us of Python + pyopencl per step with every kernel launch stubbed out (what the host costs before
the driver), launches and host syncs per step.

Queues profile only when asked (docs/perf_notes.md §12): the wall timings run on the default, unprofiled queue
and the device breakdown is left out; REINGS_QUEUE_PROFILING=1 adds it (and slows our wall on NVIDIA).

Importable without torch (gsplat's side imports it only when it runs).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # peer_gsplat


def ours_step(be, g, cam, target, warmup, repeats, breakdown=True, count=True) -> dict:
    from reings.bench import bench_train_step

    return bench_train_step(be, g, cam, target, warmup=warmup, repeats=repeats, breakdown=breakdown, count=count)


def ours_image(be, g, cam) -> np.ndarray:
    """Our forward image of `g` through the device engine (the step's forward)."""
    from reings.bench import make_step_trainer

    t, _ = make_step_trainer(be, g, np.zeros((cam.height, cam.width, 3), np.float32))
    return t.read_rgb(t.forward(cam, t.kmax, (0.0, 0.0, 0.0), 0.01))


def gsplat_available() -> str | None:
    """None if torch with CUDA and gsplat import, else the reason."""
    try:
        import torch
        import gsplat  # noqa: F401
    except Exception as e:  # pragma: no cover - depends on the machine
        return f"{type(e).__name__}: {e}"
    if not torch.cuda.is_available():
        return "torch has no CUDA device"
    return None


def gsplat_step(g, cam, sh, target, warmup=8, repeats=40) -> dict:
    """bench/peer_gsplat.py's training step on these arrays (same forward / loss / optimizer), timed
    with its _time_cuda; plus its image at the initial parameters and visible / intersections."""
    import torch
    from gsplat import rasterization

    from peer_gsplat import _time_cuda

    dev = torch.device("cuda")
    W, H = cam.width, cam.height
    t = lambda a: torch.tensor(np.asarray(a), device=dev, dtype=torch.float32)  # noqa: E731
    params = {"means": t(g.means).requires_grad_(), "quats": t(g.quats).requires_grad_(),
              "log_scales": t(g.log_scales).requires_grad_(), "logits": t(g.opacity_logits).requires_grad_(),
              "sh": t(g.sh).requires_grad_()}
    view, Ks = t(cam.viewmat)[None], t(cam.K)[None]
    tgt = t(target)

    def forward():
        img, alpha, meta = rasterization(
            params["means"], params["quats"], torch.exp(params["log_scales"]), torch.sigmoid(params["logits"]),
            params["sh"], view, Ks, W, H, near_plane=0.01, sh_degree=sh, packed=False)
        return img[0], meta

    with torch.no_grad():
        img0, meta = forward()
        img0 = img0.detach().cpu().numpy()
        radii = meta["radii"]
        visible = int((radii > 0).any(-1).sum().item()) if radii.dim() == 3 else int((radii > 0).sum().item())
        isects = int(meta["isect_ids"].numel()) if "isect_ids" in meta else None
    opt = torch.optim.Adam(list(params.values()), lr=1e-3, eps=1e-15, fused=True)

    def step():
        img, _ = forward()
        loss = (img - tgt).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    ev, wall = _time_cuda(torch, step, warmup=warmup, repeats=repeats)
    peak = torch.cuda.max_memory_allocated() / 2**20  # since the reset in run_config
    return dict(gsplat_step_ms=ev, gsplat_step_wall_ms=wall, gsplat_visible=visible, gsplat_intersections=isects,
                gsplat_device=torch.cuda.get_device_name(), gsplat_peak_mb=peak, image=img0)


def run_config(be, scene, sh, args, gs_reason, mem=None) -> dict:
    from reings.backends.opencl.harness import device_info
    from reings.bench import step_reference_error, step_target
    from reings.bench_scenes import perf_scene

    g, cam = perf_scene(scene, sh_degree=sh, n=args.n)
    target = step_target(cam)
    row = dict(kind="step", scene=scene, sh=sh, N=len(g), width=cam.width, height=cam.height)
    row.update({k: v for k, v in device_info(be).items() if k in ("device", "driver", "spec")})
    from reings.backends.opencl.trainer import DeviceTrainer

    row["flush_after_forward"] = DeviceTrainer.flush_after_forward
    if mem is not None:
        import gc

        gc.collect()  # the previous configuration's trainer is gone: start the peak from what lives
        mem.reset_peak()
    r = ours_step(be, g, cam, target, args.warmup, args.repeats, breakdown=not args.no_breakdown)
    if mem is not None:
        row["ours_peak_mb"] = mem.peak_bytes / 2**20  # buffers alive during this step (scratch kept from earlier scenes included)
    row.update({f"ours_{k}": v for k, v in r.items() if k not in ("n", "sh_k", "width", "height")})
    row["visible"], row["intersections"] = r["visible"], r["intersections"]
    img = ours_image(be, g, cam)
    if args.ref_crop >= 0:
        row.update(step_reference_error(be, g, cam, args.ref_crop))
    if gs_reason is None:
        import torch

        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
        gr = gsplat_step(g, cam, sh, target, args.gs_warmup, args.gs_repeats)
        gimg = gr.pop("image")
        row.update(gr)
        row["ratio_wall"] = row["ours_step_wall_ms"] / row["gsplat_step_wall_ms"]
        row["ratio_vs_event"] = row["ours_step_wall_ms"] / row["gsplat_step_ms"]
        if args.rounds > 1:  # interleaved: ours, gsplat, ours, gsplat, ... (host drift hits both sides alike)
            ours_r, gs_r, gs_ev = [row["ours_step_wall_ms"]], [row["gsplat_step_wall_ms"]], [row["gsplat_step_ms"]]
            for _ in range(args.rounds - 1):  # each round warmed up as the first
                ours_r.append(ours_step(be, g, cam, target, args.warmup, args.repeats, breakdown=False,
                                        count=False)["step_wall_ms"])
                gr = gsplat_step(g, cam, sh, target, args.gs_warmup, args.gs_repeats)
                gs_r.append(gr["gsplat_step_wall_ms"])
                gs_ev.append(gr["gsplat_step_ms"])
            ratios = [o / s for o, s in zip(ours_r, gs_r)]
            row.update(ours_step_wall_ms_rounds=ours_r, gsplat_step_wall_ms_rounds=gs_r, gsplat_step_ms_rounds=gs_ev,
                       ratio_wall_rounds=ratios, ratio_wall_first=row["ratio_wall"], ratio_wall=statistics.median(ratios),
                       ratio_vs_event=statistics.median(o / e for o, e in zip(ours_r, gs_ev)),
                       ours_step_wall_ms=statistics.median(ours_r), gsplat_step_wall_ms=statistics.median(gs_r),
                       gsplat_step_ms=statistics.median(gs_ev))
        d = np.abs(img.astype(np.float64) - gimg.astype(np.float64))
        row["vs_gsplat_mean_abs"], row["vs_gsplat_max_abs"] = float(d.mean()), float(d.max())
    return row


def _f(x, nd=2):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return f"{x:.{nd}f}" if isinstance(x, float) else str(x)


def print_table(rows, file=sys.stdout):
    if not rows:
        return
    print(f"\n# ours: {rows[0].get('device')} | driver {rows[0].get('driver')}; gsplat: "
          f"{rows[0].get('gsplat_device', 'not run')}", file=file)
    hdr = ("scene", "sh", "visible", "isects", "ours ms", "ours dev", "ours span", "gs ev ms", "gs wall",
           "ours/gs", "launch", "syncs", "err f64", "vs gs mean")
    print(" ".join(f"{h:>10}" for h in hdr), file=file)
    for r in rows:
        ps = r.get("ours_per_step", {})
        vals = (r["scene"], r["sh"], r["visible"], r["intersections"], _f(r["ours_step_wall_ms"]),
                _f(r.get("ours_dev_sum_ms")), _f(r.get("ours_dev_span_ms")), _f(r.get("gsplat_step_ms")),
                _f(r.get("gsplat_step_wall_ms")), _f(r.get("ratio_wall"), 3), _f(ps.get("launches"), 0),
                _f(ps.get("syncs"), 0),
                "-" if "max_err_rgb_vs_f64" not in r else f"{r['max_err_rgb_vs_f64']:.1e}",
                "-" if "vs_gsplat_mean_abs" not in r else f"{r['vs_gsplat_mean_abs']:.1e}")
        print(" ".join(f"{str(v):>10}" for v in vals), file=file)
    print("(ms per training step, medians. ours ms: wall clock incl. a queue.finish per step; ours dev: sum of "
          "device time per stage from profiling events; ours span: first kernel start to last kernel end; gs ev / "
          "gs wall: gsplat's CUDA-event / wall-clock-with-synchronize step; ours/gs: wall / wall; launch, syncs: "
          "OpenCL kernel launches and host syncs per step; err f64: max |rgb - float64 reference| on the "
          "--ref-crop window; vs gs mean: mean |rgb - gsplat rgb|)", file=file)
    for r in rows:
        if "vs_gsplat_max_abs" in r:
            print(f"accuracy {r['scene']}-sh{r['sh']}: max|ours - f64| {r.get('max_err_rgb_vs_f64', float('nan')):.2e} "
                  f"(crop {r.get('ref_crop')}); |ours - gsplat| mean {r['vs_gsplat_mean_abs']:.2e} max "
                  f"{r['vs_gsplat_max_abs']:.2e}; visible ours/gsplat {r['visible']}/{r['gsplat_visible']}, "
                  f"intersections {r['intersections']}/{r['gsplat_intersections']}", file=file)
        elif "max_err_rgb_vs_f64" in r:
            print(f"accuracy {r['scene']}-sh{r['sh']}: max|ours - f64| {r['max_err_rgb_vs_f64']:.2e} "
                  f"(crop {r.get('ref_crop')}); gsplat not run", file=file)
    for r in rows:
        if "ours_peak_mb" in r or "gsplat_peak_mb" in r:
            print(f"memory {r['scene']}-sh{r['sh']}: ours peak {_f(r.get('ours_peak_mb'), 1)} MB (OpenCL buffers "
                  f"alive during the step), gsplat peak {_f(r.get('gsplat_peak_mb'), 1)} MB "
                  f"(torch.cuda.max_memory_allocated)", file=file)
    for r in rows:
        st = sorted(((k[len("ours_dev_"):-3], v) for k, v in r.items() if k.startswith("ours_dev_")
                     and k.endswith("_ms") and k not in ("ours_dev_sum_ms", "ours_dev_span_ms")), key=lambda kv: -kv[1])
        if st:
            print(f"device ms {r['scene']}-sh{r['sh']}: " + ", ".join(f"{k} {v:.3f}" for k, v in st), file=file)


# ------------------------------------------------------------------------------------------------
# host overhead on a tiny image
# ------------------------------------------------------------------------------------------------
def overhead(be, size=32, n=2000, sh=3, steps=300, rounds=7) -> dict:
    """Host cost of one step where the kernels are negligible (module docstring, --overhead); the
    us figures are the minimum over `rounds` rounds of `steps` steps (…_median: the median)."""
    from reings.backends.opencl.harness import ClCalls, launches_stubbed
    from reings.bench import crop_camera, make_step_trainer, step_target
    from reings.bench_scenes import perf_scene

    g, cam = perf_scene("A", sh_degree=sh, n=n)
    cc = crop_camera(cam, size)
    t, opt = make_step_trainer(be, g, step_target(cc))
    q = be.queue
    for _ in range(20):
        t.step_l1(cc, 0, opt)
    q.finish()

    def timed(finish_each):
        res = []
        for _ in range(rounds):
            t0, c0 = time.perf_counter(), time.thread_time()
            for _ in range(steps):
                t.step_l1(cc, 0, opt)
                if finish_each:
                    q.finish()
            q.finish()
            res.append(((time.perf_counter() - t0) / steps * 1e6, (time.thread_time() - c0) / steps * 1e6))
        return min(w for w, _ in res), statistics.median(w for w, _ in res)

    rec = dict(kind="overhead", size=[cc.width, cc.height], n=n, sh=sh)
    with ClCalls() as cc_:
        fr, _ = t.step_l1(cc, 0, opt)
        q.finish()
    rec["per_step"] = cc_.as_dict()
    rec["per_step"]["finishes"] -= 1
    rec["per_step"]["syncs"] -= 1
    rec["visible"], rec["intersections"] = fr.visible, fr.isects
    rec["wall_us_finish_each"], rec["wall_us_finish_each_median"] = timed(True)
    with launches_stubbed():
        rec["python_us_launches_stubbed"], rec["python_us_launches_stubbed_median"] = timed(False)
    q.finish()
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", help="OpenCL device: cuda, pocl, opencl:P:D")
    ap.add_argument("--scenes", default="A,B,C")
    ap.add_argument("--sh", default="0,3")
    ap.add_argument("--n", type=int, default=None, help="override the Gaussian count (smoke runs)")
    ap.add_argument("--warmup", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=40)
    ap.add_argument("--gs-warmup", type=int, default=8)
    ap.add_argument("--gs-repeats", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=1,
                    help="with gsplat: alternate the two sides this many times per configuration; the walls are "
                         "the medians of the rounds' medians and the ratio the median of the per-round ratios")
    ap.add_argument("--ref-crop", type=int, default=96, help="reference comparison window (0: full, -1: skip)")
    ap.add_argument("--no-breakdown", action="store_true", help="skip the profiled per-stage run")
    ap.add_argument("--no-gsplat", action="store_true")
    ap.add_argument("--no-flush", action="store_true", help="no clFlush after the forward (A/B of that flush)")
    ap.add_argument("--overhead", action="store_true", help="host overhead per step on a tiny image only")
    ap.add_argument("--overhead-size", type=int, default=32)
    ap.add_argument("--overhead-n", type=int, default=2000)
    ap.add_argument("--json", default=None, help="append one JSON line per row to this file")
    a = ap.parse_args(argv)
    if a.rounds < 1:
        ap.error(f"--rounds must be at least 1, got {a.rounds}")

    from reings.backends import get_backend
    from reings.backends.opencl.harness import DeviceBytes

    mem = DeviceBytes().__enter__()  # tracks every OpenCL buffer from here on (peak per configuration)
    be = get_backend(a.device)
    if a.no_flush:
        from reings.backends.opencl.trainer import DeviceTrainer

        DeviceTrainer.flush_after_forward = False
    rows = []

    def emit(r):
        rows.append(r)
        print(json.dumps(r), flush=True)
        if a.json:
            with open(a.json, "a") as f:
                f.write(json.dumps(r) + "\n")

    if a.overhead:
        for sh in [int(s) for s in a.sh.split(",") if s.strip()]:
            r = overhead(be, a.overhead_size, a.overhead_n, sh)
            r["device"] = be.device_name
            emit(r)
            ps = r["per_step"]
            print(f"# overhead sh{sh} {r['size']} N={r['n']} (vis {r['visible']}, K {r['intersections']}): "
                  f"wall {r['wall_us_finish_each']:.0f} us/step (finish each; median of rounds "
                  f"{r['wall_us_finish_each_median']:.0f}); python+pyopencl with launches stubbed "
                  f"{r['python_us_launches_stubbed']:.0f} us/step (median {r['python_us_launches_stubbed_median']:.0f}); launches {ps['launches']:.0f}, "
                  f"syncs {ps['syncs']:.0f}, copies {ps['copies']:.0f}", flush=True)
        return 0

    gs_reason = "--no-gsplat" if a.no_gsplat else gsplat_available()
    if gs_reason is not None:
        print(f"peer_step: gsplat side skipped ({gs_reason})" + ("; --rounds needs it: one round" if a.rounds > 1 else ""),
              flush=True)
    for scene in [s.strip() for s in a.scenes.split(",") if s.strip()]:
        for sh in [int(s) for s in a.sh.split(",") if s.strip()]:
            emit(run_config(be, scene, sh, a, gs_reason, mem))
    print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
