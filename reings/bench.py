"""`reings bench`: the splatting core on the docs/perf_notes.md §1.7 scenes, per stage and whole fwd+bwd.

    reings bench [--device pocl] [--scenes A,B,C] [--sh 0,3] [--warmup 8] [--repeats 40]
                 [--sort all|ours|none] [--reference crop|none] [--pairs reference|estimate|none]
                 [--step] [--out FILE.jsonl]
    python -c "from reings.bench import main; main(['--scenes', 'A', '--repeats', '10'])"

For each scene x SH degree (504x378, near 0.01, black background): `render` then the L1-mean
cotangent against a fixed random target, then `render_vjp` (the forward is reused on CPU devices,
see OpenCLBackend). Reported per configuration, as the median over `repeats` after `warmup`:
  * wall clock of render, of the cotangent, of render_vjp, and of the whole step (Python included,
    the one control readback and the output reads included);
  * device time per stage from the queue's profiling events (OpenCLBackend.last_profile);
  * visible Gaussians, intersections, evaluated (pixel, Gaussian) pairs and pairs/s. Evaluated pairs
    ("reference") are counted by the float64 reference on the full image (once per scene: the count
    does not depend on colours), or ("estimate") bounded from the device's own outputs;
  * the error against the float64 reference on a centred crop (the same camera with the principal
    point shifted; the full image would take the reference minutes): max abs error of rgb / alpha /
    depth (depth relative to the largest depth) and per-field gradient cosine and relative L2.
Per scene, the sort (reings.backends.opencl.harness.sort_comparison): numpy.argsort(kind="stable")
vs our radix sort (reings.backends.opencl.sort) vs pyopencl.algorithm.RadixSort on the scene's own
(tile << 32 | depth bits) keys in gid emit order (gsplat's layout, end bit 32 + ceil(log2 tiles)),
plus our pipeline's two 32-bit sorts as they run in the render; and once, the same on 1M synthetic
keys.
With --step, per configuration also the device engine's training step (bench_train_step:
DeviceTrainer.step_l1 = forward from device-resident parameters, L1 on the device, backward, Adam
kernel over all groups; median wall per step with a finish, device time per stage, launches and host
syncs per step); bench/peer_step.py puts gsplat's step beside it.
Output: one JSON object per line (device, driver, versions in each) and a table at the end.

The pyopencl-level instruments (command counting, buffer bytes, the pyopencl sort) live in
reings/backends/opencl/harness.py; this module drives them through the backend and the trainer.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np

from .backends.opencl.harness import ClCalls, device_info, sort_comparison

STAGES_FWD = ("project_fwd", "sort_depth", "bin_count", "scan", "bin_emit", "sort_tile", "tile_ranges",
              "rasterize_fwd")
STAGES_BWD = ("rasterize_bwd", "isect_reduce", "project_bwd")
FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def _median(xs):
    return float(statistics.median(xs)) if xs else float("nan")


def crop_camera(cam, size: int):
    """The centred size x size window of `cam` (same intrinsics, principal point shifted)."""
    from .types import Camera

    w, h = min(size, cam.width), min(size, cam.height)
    x0, y0 = (cam.width - w) // 2, (cam.height - h) // 2
    K = cam.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, cam.viewmat, w, h)


def reference_error(be, g, cam, crop: int) -> dict:
    """Device vs float64 reference on a centred crop: forward max errors and gradient agreement."""
    from .backends import reference as ref

    cc = crop_camera(cam, crop)
    rng = np.random.default_rng(1)
    v_rgb = rng.normal(size=(cc.height, cc.width, 3)).astype(np.float32)
    out = be.render(g, cc)
    _, _, o64, stats = ref.render64(g, cc)
    zmax = max(1.0, float(np.max(o64.depth / np.maximum(o64.alpha, 1e-6), initial=1.0)))
    res = dict(crop=[cc.width, cc.height], crop_visible=stats["visible"],
               crop_intersections=stats["intersections"],
               max_err_rgb=float(np.abs(out.rgb - o64.rgb).max()),
               max_err_alpha=float(np.abs(out.alpha - o64.alpha).max()),
               max_err_depth_rel=float(np.abs(out.depth - o64.depth).max() / zmax),
               pixels_over_1e4=int(np.count_nonzero(np.abs(out.alpha - o64.alpha) > 1e-4)))
    gd = be.render_vjp(g, cc, v_rgb)
    ge = ref.render_vjp64(g, cc, v_rgb)
    for f in FIELDS:
        a, e = getattr(gd, f).astype(np.float64).ravel(), getattr(ge, f).ravel()
        na, ne = np.linalg.norm(a), np.linalg.norm(e)
        res[f"grad_cos_{f}"] = float(a @ e / (na * ne)) if na > 0 and ne > 0 else float(na == ne)
        res[f"grad_rel_l2_{f}"] = float(np.linalg.norm(a - e) / ne) if ne > 0 else float(na)
    return res


def reference_pairs(g, cam) -> int:
    """Evaluated (pixel, Gaussian) pairs of the float64 reference on the full image."""
    from .backends import reference as ref

    p = ref.project_fwd(g, cam)
    b = ref.bin(p, cam.width, cam.height)
    return int(ref.rasterize_fwd(p, b, cam.width, cam.height).evaluated_pairs)


def estimate_pairs(be, g, cam) -> int:
    """Evaluated pairs bounded from the device's outputs: a pixel with final T >= 0.01 cannot have
    stopped early (T (1 - alpha) >= 1e-4 for every alpha <= 0.99), so it examined its whole tile list;
    any other pixel is counted as last + 1 (its last blended entry plus the one that stopped it)."""
    from .backends.base import TILE_SIZE, tile_grid

    p = be.project_fwd(g, cam)
    b = be.bin(p, cam.width, cam.height)
    out = be.rasterize_fwd(p, b, cam.width, cam.height)
    tx, ty = tile_grid(cam.width, cam.height)
    lens = (b.tile_ranges[:, 1] - b.tile_ranges[:, 0]).reshape(ty, tx)
    per_px = np.repeat(np.repeat(lens, TILE_SIZE, 0), TILE_SIZE, 1)[:cam.height, :cam.width]
    cnt = np.where(out.final_T >= 0.01, per_px, np.minimum(out.last + 1, per_px))
    return int(cnt.sum())


# ------------------------------------------------------------------------------------------------
# sort comparison
# ------------------------------------------------------------------------------------------------
def emit_keys_gid_order(be, g, cam) -> tuple[np.ndarray, int]:
    """(tile << 32 | float bits of depth) per intersection, Gaussians in gid order, tiles row-major
    (gsplat's isect_tiles layout); returns (keys uint64, tile bits)."""
    from .backends.base import tile_grid
    from .backends.opencl.backend import tile_bits

    p = be.project_fwd(g, cam)
    vis = np.flatnonzero(p.radii > 0)
    r = p.tile_rect[vis].astype(np.int64)
    w, h = r[:, 2] - r[:, 0], r[:, 3] - r[:, 1]
    cnt = w * h
    owner = np.repeat(np.arange(len(vis)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    tx, _ = tile_grid(cam.width, cam.height)
    tile = (r[owner, 1] + local // w[owner]) * tx + r[owner, 0] + local % w[owner]
    dbits = p.depths[vis].astype(np.float32).view(np.uint32).astype(np.uint64)[owner]
    keys = (tile.astype(np.uint64) << np.uint64(32)) | dbits
    return keys, tile_bits(tx * tile_grid(cam.width, cam.height)[1])


def synthetic_keys(n: int, tbits: int = 10, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tile = rng.integers(0, 1 << tbits, n).astype(np.uint64)
    depth = rng.uniform(2.0, 8.0, n).astype(np.float32).view(np.uint32).astype(np.uint64)
    return (tile << np.uint64(32)) | depth


# ------------------------------------------------------------------------------------------------
# one configuration
# ------------------------------------------------------------------------------------------------
def bench_config(be, scene: str, sh: int, args) -> dict:
    from .bench_scenes import perf_scene

    g, cam = perf_scene(scene, sh_degree=sh, n=args.n)
    H, W = cam.height, cam.width
    target = np.random.default_rng(123).uniform(0.0, 1.0, (H, W, 3)).astype(np.float32)
    inv = np.float32(1.0 / (H * W * 3))
    rec: dict = dict(kind="render", scene=scene, sh_degree=sh, n=len(g), width=W, height=H)
    wall = {k: [] for k in ("fwd", "loss", "bwd", "step")}
    dev = {s: [] for s in STAGES_FWD + STAGES_BWD}
    for i in range(args.warmup + args.repeats):
        t0 = time.perf_counter()
        out = be.render(g, cam)
        pf = dict(be.last_profile)
        t1 = time.perf_counter()
        v_rgb = np.sign(out.rgb - target) * inv  # d/d rgb of mean |rgb - target|
        t2 = time.perf_counter()
        be.render_vjp(g, cam, v_rgb)
        pb = dict(be.last_profile)
        t3 = time.perf_counter()
        if i < args.warmup:
            continue
        for k, v in (("fwd", t1 - t0), ("loss", t2 - t1), ("bwd", t3 - t2), ("step", t3 - t0)):
            wall[k].append(1e3 * v)
        for s in dev:
            dev[s].append(pf.get(s, pb.get(s, 0.0)))
    rec.update(visible=out.stats["visible"], intersections=out.stats["intersections"])
    rec.update({f"wall_{k}_ms": _median(v) for k, v in wall.items()})
    rec.update({f"dev_{s}_ms": _median(v) for s, v in dev.items()})
    rec["dev_fwd_ms"] = sum(rec[f"dev_{s}_ms"] for s in STAGES_FWD)
    rec["dev_bwd_ms"] = sum(rec[f"dev_{s}_ms"] for s in STAGES_BWD)
    return rec


# ------------------------------------------------------------------------------------------------
# the training step (device-resident engine), gsplat's step workload
# ------------------------------------------------------------------------------------------------
def step_target(cam, seed: int = 123) -> np.ndarray:
    """The fixed random [H,W,3] float32 target of the training-step benchmark (U(0, 1))."""
    return np.random.default_rng(seed).uniform(0.0, 1.0, (cam.height, cam.width, 3)).astype(np.float32)


def make_step_trainer(be, g, target, lr: float = 1e-3, eps: float = 1e-15, adam: str = "kernel"):
    """(device trainer, Adam) holding Gaussians `g` (all SH coefficients trained) and `target` as
    training image 0, every group at learning rate `lr` (gsplat peer: torch Adam lr 1e-3, eps 1e-15)."""
    from .densify import init_stats
    from .optim import Adam
    from .state import PARAM_NAMES, TrainState

    st = TrainState.from_gaussians(g)
    init_stats(st)
    t = be.trainer([target], engine="device", adam=adam)
    t.upload(st)
    opt = Adam(st.params, {k: lr for k in PARAM_NAMES}, state=st.adam, eps=eps)
    return t, opt


def bench_train_step(be, g, cam, target=None, warmup: int = 8, repeats: int = 40, breakdown: bool = True,
                     count: bool = True, adam: str = "kernel") -> dict:
    """Our training step on the device engine (DeviceTrainer.step_l1: forward from the device
    parameters, L1 vs `target`, backward, Adam over all groups; no loss read), timed like
    bench/peer_gsplat.py's: median wall clock per step with a queue.finish() after each, after
    `warmup` steps. Also: OpenCL launches / host syncs per step (ClCalls), the host time per step
    until the final finish is called ("step_host_enqueue_ms": enqueueing plus, in the sync binning, the
    binning's wait for (V, K)), and with `breakdown` a
    second run with profiling events -> device ms per stage ("dev_<stage>_ms"), their sum, and the
    device span (first kernel start to last kernel end), when the backend's queue profiles
    (`set_queue_profiling`; `reings bench` turns it on, so its wall is a profiled queue's). The parameters move with every step
    (restore them with trainer.upload if needed)."""
    target = step_target(cam) if target is None else target
    t, opt = make_step_trainer(be, g, target, adam=adam)
    q = be.queue
    for _ in range(warmup):
        t.step_l1(cam, 0, opt)
    q.finish()
    wall, host = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fr, _ = t.step_l1(cam, 0, opt)
        t1 = time.perf_counter()
        q.finish()
        t2 = time.perf_counter()
        wall.append(1e3 * (t2 - t0))
        host.append(1e3 * (t1 - t0))
    rec = dict(step_wall_ms=_median(wall), step_wall_min_ms=min(wall) if wall else float("nan"),
               step_host_enqueue_ms=_median(host), visible=fr.visible, intersections=fr.isects,
               n=t.n, sh_k=t.kmax, width=cam.width, height=cam.height)
    if count:
        with ClCalls() as cc:
            reps = max(1, min(repeats, 5))
            for _ in range(reps):
                t.step_l1(cam, 0, opt)
            q.finish()
        rec["per_step"] = cc.as_dict(reps)
        rec["per_step"]["finishes"] -= 1 / reps  # the final finish of the counted block
        rec["per_step"]["syncs"] -= 1 / reps
    if breakdown and getattr(be.handle, "profiling", False):  # device ms need a profiling queue
        prof: dict = {}
        t.profile = prof
        spans = []
        reps = max(1, min(repeats, 10))
        for _ in range(reps):
            t.finish()
            prof.pop("device_ms", None)
            t.step_l1(cam, 0, opt)
            span = t.device_span_ms()
            if span is not None:
                spans.append(span)
            t.finish()
            for st, ms in prof.get("device_ms", {}).items():
                rec.setdefault(f"dev_{st}_ms_all", []).append(ms)
        t.profile = None
        for key in [k for k in rec if k.endswith("_ms_all")]:
            rec[key[:-4]] = _median(rec.pop(key))
        rec["dev_sum_ms"] = sum(v for k, v in rec.items() if k.startswith("dev_") and k.endswith("_ms")
                                and k != "dev_sum_ms")
        rec["dev_span_ms"] = _median(spans)
    return rec


def step_reference_error(be, g, cam, crop: int = 96) -> dict:
    """Our device engine's forward image (device parameters, as the step renders them) vs the
    float64 reference on the centred crop x crop window (0: the full image): max abs rgb error."""
    from .backends import reference as ref

    cc = crop_camera(cam, crop) if crop else cam
    t, _ = make_step_trainer(be, g, np.zeros((cc.height, cc.width, 3), np.float32))
    rgb = t.read_rgb(t.forward(cc, t.kmax, (0.0, 0.0, 0.0), 0.01))
    _, _, o64, _ = ref.render64(g, cc)
    return dict(ref_crop=[cc.width, cc.height], max_err_rgb_vs_f64=float(np.abs(rgb - o64.rgb).max()))


def _fmt(x, nd=1):
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}f}"


def print_table(records: list[dict], file=sys.stdout):
    rr = [r for r in records if r.get("kind") == "render"]
    if rr:
        print(f"\n# {rr[0]['device']} | driver {rr[0]['driver']} | {rr[0]['platform_version']}", file=file)
        hdr = ("scene", "vis", "isects", "pairs", "fwd", "f+b", "proj", "sortD", "bin", "sortT", "rastF",
               "rastB", "red", "projB", "Mpair/s", "err_rgb", "cos_min")
        print(" ".join(f"{h:>8}" for h in hdr), file=file)
        for r in rr:
            binm = sum(r[f"dev_{s}_ms"] for s in ("bin_count", "scan", "bin_emit", "tile_ranges"))
            cos = [r[k] for k in r if k.startswith("grad_cos_")]
            pairs = r.get("evaluated_pairs")
            row = (f"{r['scene']}-sh{r['sh_degree']}", r["visible"], r["intersections"],
                   "-" if pairs is None else f"{pairs / 1e6:.1f}M",
                   _fmt(r["wall_fwd_ms"]), _fmt(r["wall_step_ms"]), _fmt(r["dev_project_fwd_ms"]),
                   _fmt(r["dev_sort_depth_ms"]), _fmt(binm), _fmt(r["dev_sort_tile_ms"]),
                   _fmt(r["dev_rasterize_fwd_ms"]), _fmt(r["dev_rasterize_bwd_ms"]), _fmt(r["dev_isect_reduce_ms"]),
                   _fmt(r["dev_project_bwd_ms"]), _fmt(r.get("pairs_per_s_step", float("nan")) / 1e6),
                   "-" if "max_err_rgb" not in r else f"{r['max_err_rgb']:.1e}",
                   "-" if not cos else f"{min(cos):.6f}")
            print(" ".join(f"{str(x):>8}" for x in row), file=file)
        print("(ms; fwd / f+b: wall clock of render / render+loss+render_vjp; other stage columns: device "
              "time from profiling events; Mpair/s: evaluated pairs per second of the whole step)", file=file)
    st = [r for r in records if r.get("kind") == "step"]
    if st:
        print("\n# training step on the device engine (forward, L1, backward, Adam over all groups): ms", file=file)
        print(f"{'scene':>8} {'vis':>8} {'isects':>8} {'wall':>8} {'enqueue':>8} {'dev sum':>8} {'dev span':>8} "
              f"{'launch':>7} {'syncs':>6}", file=file)
        for r in st:
            ps = r.get("per_step", {})
            print(f"{r['scene'] + '-sh' + str(r['sh_degree']):>8} {r['visible']:>8} {r['intersections']:>8} "
                  f"{_fmt(r['step_wall_ms'], 2):>8} {_fmt(r['step_host_enqueue_ms'], 2):>8} "
                  f"{_fmt(r.get('dev_sum_ms'), 2):>8} {_fmt(r.get('dev_span_ms'), 2):>8} "
                  f"{_fmt(ps.get('launches'), 0):>7} {_fmt(ps.get('syncs'), 0):>6}", file=file)
        print("(wall: median per step incl. a queue.finish; enqueue: host time until the finish; dev sum: device "
              "time per stage from profiling events; dev span: first kernel start to last kernel end)", file=file)
    sr = [r for r in records if r.get("kind") == "sort"]
    if sr:
        print("\n# sort of (tile, depth) keys: ms (wall, median)", file=file)
        print(f"{'keys':>10} {'n':>9} {'bits':>5} {'numpy':>8} {'ours':>8} {'pyopencl':>9} {'x numpy':>8} "
              f"{'pipeline 2x32':>13}", file=file)
        for r in sr:
            print(f"{r['keys']:>10} {r['n']:>9} {r['end_bit']:>5} {_fmt(r['numpy_ms']):>8} "
                  f"{_fmt(r.get('ours_ms')):>8} {_fmt(r.get('pyopencl_ms')):>9} "
                  f"{_fmt(r.get('speedup_vs_numpy'), 2):>8} {_fmt(r.get('pipeline_two_sorts_ms')):>13}", file=file)


def _int_at_least(lo: int):
    """argparse type: an integer >= lo (the error names the value; argparse names the option)."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {v}")
        return v
    return parse


def _sh_list(text: str) -> list[int]:
    """argparse type of --sh: a comma list of SH degrees 0..3."""
    try:
        degs = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma list of SH degrees 0..3, got {text!r}") from None
    if not degs or any(not 0 <= d <= 3 for d in degs):
        raise argparse.ArgumentTypeError(f"SH degrees must lie in 0..3, got {text!r}")
    return degs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="reings bench", description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="pocl", help="pocl, cuda, oclgrind or opencl:P:D")
    ap.add_argument("--scenes", default="A,B,C", help="comma list of docs/perf_notes.md §1.7 scenes")
    ap.add_argument("--sh", default=[0, 3], type=_sh_list, help="comma list of SH degrees (0..3)")
    ap.add_argument("--n", type=_int_at_least(1), default=None, help="override the Gaussian count (smoke runs)")
    ap.add_argument("--warmup", type=_int_at_least(0), default=8)
    ap.add_argument("--repeats", type=_int_at_least(1), default=40)
    ap.add_argument("--sort", choices=("all", "ours", "none"), default="all",
                    help="sort comparison: numpy + ours + pyopencl RadixSort, numpy + ours, or none")
    ap.add_argument("--sort-n", type=_int_at_least(0), default=1_000_000, help="synthetic key count (0: skip)")
    ap.add_argument("--reference", choices=("crop", "none"), default="crop")
    ap.add_argument("--crop", type=_int_at_least(1), default=96, help="crop size for the reference comparison")
    ap.add_argument("--pairs", choices=("reference", "estimate", "none"), default="reference")
    ap.add_argument("--step", action="store_true",
                    help="also time the device engine's training step (forward, L1, backward, Adam kernel: "
                         "DeviceTrainer.step_l1, gsplat's step workload; bench/peer_step.py runs gsplat beside it)")
    ap.add_argument("--out", default=None, help="write the JSON lines here instead of stdout")
    args = ap.parse_args(argv)

    from .backends import get_backend, set_queue_profiling

    set_queue_profiling(True)  # the stage times are read from the queue's profiling events
    be = get_backend(args.device)  # the registry's instance: kernels and buffers shared with render()
    if not getattr(getattr(be, "handle", None), "profiling", True):
        print(f"reings bench: the {args.device!r} queue was opened without profiling earlier in this process: "
              "device times per stage are not available (wall times are)", file=sys.stderr)
    if "device" not in be.engines:  # the stage timings and the step need a device-resident backend
        raise SystemExit(f"reings bench: {args.device!r} is not an OpenCL device")
    info = device_info(be)
    sink = open(args.out, "a") if args.out else sys.stdout
    records: list[dict] = []

    def emit(rec):
        rec = {**info, **rec}
        records.append(rec)
        print(json.dumps(rec), file=sink, flush=True)

    from .bench_scenes import perf_scene

    for scene in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        pairs = None
        for sh in args.sh:
            rec = bench_config(be, scene, sh, args)
            if args.pairs != "none" and pairs is None:
                g, cam = perf_scene(scene, sh_degree=0, n=args.n)
                pairs = reference_pairs(g, cam) if args.pairs == "reference" else estimate_pairs(be, g, cam)
            if pairs is not None:
                rec["evaluated_pairs"] = pairs
                rec["pairs_source"] = args.pairs
                rec["pairs_per_s_step"] = pairs / (rec["wall_step_ms"] * 1e-3)
                rec["pairs_per_s_raster_fwd"] = pairs / max(rec["dev_rasterize_fwd_ms"] * 1e-3, 1e-12)
            if args.reference == "crop":
                g, cam = perf_scene(scene, sh_degree=sh, n=args.n)
                rec.update(reference_error(be, g, cam, args.crop))
            emit(rec)
            if args.step:
                g, cam = perf_scene(scene, sh_degree=sh, n=args.n)
                srec = bench_train_step(be, g, cam, warmup=args.warmup, repeats=args.repeats)
                emit(dict(kind="step", scene=scene, sh_degree=sh, **srec))
        if args.sort != "none":
            g, cam = perf_scene(scene, sh_degree=0, n=args.n)
            keys, tbits = emit_keys_gid_order(be, g, cam)
            srec = dict(kind="sort", keys=f"scene {scene}", scene=scene,
                        **sort_comparison(be, keys, tbits, args.repeats, args.warmup, args.sort))
            srec["pipeline_two_sorts_ms"] = (records[-1]["dev_sort_depth_ms"] + records[-1]["dev_sort_tile_ms"]
                                             if records and records[-1].get("scene") == scene else None)
            emit(srec)
    if args.sort != "none" and args.sort_n > 0:
        keys = synthetic_keys(args.sort_n)
        emit(dict(kind="sort", keys="synthetic", **sort_comparison(be, keys, 10, args.repeats, args.warmup,
                                                                   args.sort)))
    print_table(records, file=sys.stdout if args.out else sys.stderr)
    if args.out:
        sink.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
