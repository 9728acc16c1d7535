"""`reings run` / `reings.run`: one scene, end to end.

    data -> few-shot split (training side gets ONLY the training views) -> depth prior ->
    method stages -> test-view evaluation -> outputs

Methods:
    3dgs        random init, 3DGS losses, no depth terms
    dngaussian  random init, DNGaussian recipe (hard + soft depth)
    reings      EHPS -> coarse (photometric + hard depth) -> IVPS -> fine (+ soft depth)
                -> CVPS -> final (+ soft depth)   (paper Eq. 4-9; METHOD.md §1)
                -> final prune (ReInGSConfig.final_prune: the lowest 10% by Omega_G; not in the paper)
    reings-no-ehps, reings-no-ivps, reings-no-cvps (combinable: reings-no-ivps-no-cvps)
                the paper's Table 4 ablations (ReInGSConfig.ehps/ivps/cvps = False)

Outputs in --out (docs/pipeline.md): `metrics.json` (written last: its presence marks a finished
run; per image and mean PSNR/SSIM/LPIPS/AVGE, seconds per stage, Gaussian counts and parameter
bytes after each stage, peak host and device memory, device, the full config, the test-PSNR
against seconds series), `psnr_vs_time.svg`, `gaussians.ply`, `renders/<name>.png`,
`depths/<name>.png`, `checkpoints/` (`run.json` = the settings, one .npz per stage: a rerun
into the same --out resumes; other settings are refused unless --overwrite, which starts over).
"""
from __future__ import annotations

import dataclasses
import json
import os
import resource
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .train import fit, gaussians_from_points, random_points_in_box, scene_extent, with_iterations

QUICK_ITERS = {"3dgs": 600, "dngaussian": 600, "reings": (200, 200, 600)}
PAPER_ITERS = {"3dgs": 6000, "dngaussian": 6000, "reings": (6000, 6000, 6000)}
METHODS = ("reings", "dngaussian", "3dgs")
ABLATIONS = ("ehps", "ivps", "cvps")  # ReInGSConfig switches, in pipeline order
ABLATION_METHODS = ("reings-no-ehps", "reings-no-ivps", "reings-no-cvps")


@dataclass
class ReInGSConfig:
    """ReInGS re-initialisation settings (paper §3; METHOD.md §1.3-1.5). Defaults = the paper /
    METHOD.md proposals, except ivps_depth (see its comment)."""

    gamma: float = 1.4  # EHPS: expansion of the SfM box about its centre
    beta1: float = 200.0  # EHPS: uniform grid points = beta1 * max side of the expanded box
    beta2: float = 50.0  # EHPS: random points = beta2 * max side of the expanded box
    min_init_points: int = 2000  # EHPS: floor on the total (scenes in small units)
    delta: float = 0.03  # IVPS: weight of the depth-consistency score
    ivps_fraction: float = 0.10  # IVPS: fraction of pixels sampled per training view
    ivps_hard_opacity: float = 0.99  # IVPS: forced opacity of the depth render (Eq. 5)
    ivps_min_alpha: float = 0.5  # IVPS: pixels with hard alpha below this get score 0
    # IVPS: the depth D of Eq. 4-5 (scoring and back-projection). "hard": the paper's Eq. 5, every
    # opacity forced to ivps_hard_opacity, so the FIRST Gaussian along the ray wins whatever its real
    # opacity. "expected": the normal render's depth / alpha (real opacities), i.e. the depth at which
    # the coarse model actually composites the pixel's colour. Deviation from Eq. 5, justified by the
    # paper's own purpose for D ("map p to a corresponding scene point") and measured on the
    # procedural scene (exact depths): the coarse model keeps faint EHPS Gaussians in front of the
    # surfaces (the box is expanded by gamma), the hard depth lands ~70% in front of the true surface
    # (median |err|/z 0.68, at 200 and still 0.67 at 1200 coarse its: the scale-invariant hard-depth
    # loss never removes them), the expected depth ~15-25% (tests/test_reings_stages.py shows the mechanism).
    # Quick preset, procedural scene, test PSNR seeds 0/1: "hard" 14.90/14.87, "expected" 21.54/20.69
    # (dngaussian 18.04/18.38, reings-no-ivps 20.24/-). Default "expected"; "hard" = Eq. 5 literally.
    ivps_depth: str = "expected"
    # CVPS: fraction of the fine-stage Gaussians kept. The paper's 0.4 is the switch --cvps-fraction 0.4;
    # default 0.2 from the model-size study (docs/results.md; H200, full schedule, fern and flower at
    # 2/3/4 views): final Gaussians -12..-28%, test PSNR -0.08..+0.55 dB (mean +0.14) against 0.4
    cvps_fraction: float = 0.20
    # fraction of Gaussians with the lowest importance Omega_G (Eq. 7, summed over the TRAINING views
    # only) removed after the final optimization, before evaluation; 0 = off. Not in the paper
    # (deterministic: `prune_keep_indices`). Default 0.1 from the model-size study (docs/results.md,
    # the prune curves of 30 full-schedule runs on fern and flower at 2/3/4 views): keeping the top
    # 90% changed test PSNR by -0.02 dB on average (worst -0.22, within the run-to-run spread);
    # 80% cost 0.05 dB, 70% 0.17-0.23 dB, 50% about 1 dB.
    final_prune: float = 0.1
    ehps: bool = True  # ablation switch: False = DNGaussian-style random init
    ivps: bool = True  # ablation switch
    cvps: bool = True  # ablation switch


@dataclass
class RunResult:
    gaussians: object
    metrics: dict
    stages: list = field(default_factory=list)


# {{{ ReInGS stages

def ehps_init(extent_lo, extent_hi, rc: ReInGSConfig, sh_degree: int, rng) -> object:
    """EHPS: expand the SfM box by gamma about its centre; a uniform grid of ~beta1*max side points
    at cell centres plus beta2*max side uniform random points (METHOD.md §1.3 proposal)."""
    lo, hi = np.asarray(extent_lo, np.float64), np.asarray(extent_hi, np.float64)
    c, half = (lo + hi) / 2, (hi - lo) / 2 * rc.gamma
    lo2, hi2 = c - half, c + half
    side = hi2 - lo2
    n_uni = int(rc.beta1 * side.max())
    n_rand = int(rc.beta2 * side.max())
    if n_uni + n_rand < rc.min_init_points:  # scenes in small units: keep the 4:1 ratio
        s = rc.min_init_points / max(n_uni + n_rand, 1)
        n_uni, n_rand = int(n_uni * s), int(n_rand * s)
    step = (np.prod(side) / max(n_uni, 1)) ** (1 / 3)
    counts = np.maximum(1, np.round(side / step)).astype(int)
    axes = [lo2[a] + (np.arange(counts[a]) + 0.5) * side[a] / counts[a] for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    pts = np.concatenate([grid, random_points_in_box(lo2, hi2, n_rand, rng)]).astype(np.float32)
    return gaussians_from_points(pts, None, sh_degree, rng)


def _zscore(x, m):
    v = x[m]
    return (x - v.mean()) / (v.std() + 1e-8)


def backproject_pixels(cam, idx, z) -> np.ndarray:
    """World points [n, 3] (float64) of the flat pixel indices `idx` (row-major, v * W + u) at
    camera-space z-depths `z`: X_cam = z * ((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1) (pixel
    centres at +0.5, reings.types), X_world = R^T (X_cam - t) with viewmat = [R | t] world-to-camera."""
    idx = np.asarray(idx)
    z = np.asarray(z, np.float64)
    v, u = np.divmod(idx, cam.width)
    x = (u + 0.5 - cam.cx) / cam.fx * z
    y = (v + 0.5 - cam.cy) / cam.fy * z
    Xc = np.stack([x, y, z], 1)
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    return (Xc - t) @ R  # R^T (Xc - t)


def ivps_view_scores(g, cam, prior, rc: ReInGSConfig, device, bg, near):
    """One training view of IVPS: (score [H*W] (0 = never drawn), depth [H, W] for back-projection,
    diagnostics dict). Omega_P = delta*Omega_D + (1-delta)*Omega_T (Eq. 3-6); depth (rc.ivps_depth)
    = the hard render's (every opacity rc.ivps_hard_opacity, Eq. 5) or the normal render's depth / alpha."""
    from .rendering import render

    if rc.ivps_depth not in ("hard", "expected"):
        raise ValueError(f"ReInGSConfig.ivps_depth must be 'hard' or 'expected', got {rc.ivps_depth!r}")
    hard = render(g, cam, device, bg, near, opacity_override=rc.ivps_hard_opacity)
    soft = render(g, cam, device, bg, near)
    valid = hard.alpha >= rc.ivps_min_alpha  # some Gaussian covers the pixel
    if rc.ivps_depth == "hard":
        depth = np.where(valid, hard.depth / np.maximum(hard.alpha, 1e-6), 0.0)
    else:  # a weighted mean of the covering Gaussians' z; alpha exactly 0 would give depth 0
        valid &= soft.alpha > 1e-6
        depth = np.where(valid, soft.depth / np.maximum(soft.alpha, 1e-6), 0.0)
    omega_t = soft.final_T if soft.final_T is not None else 1.0 - soft.alpha
    omega_d = np.zeros_like(depth)
    if prior is not None and valid.sum() > 16:
        e = np.abs(_zscore(depth, valid) - _zscore(np.asarray(prior, np.float64), valid))
        ev = e[valid]
        omega_d = 1.0 - (e - ev.min()) / max(ev.max() - ev.min(), 1e-12)
    score = rc.delta * omega_d + (1 - rc.delta) * omega_t
    score = np.where(valid, np.maximum(score, 1e-6), 0.0).ravel()
    return score, depth, {"valid": valid, "omega_t": omega_t, "omega_d": omega_d}


def ivps_points(g, train, priors, rc: ReInGSConfig, device, bg, near, rng):
    """IVPS (Eq. 4-6): per view, Omega_P = delta*Omega_D + (1-delta)*Omega_T; draw ~10% of the
    pixels without replacement with p ~ Omega_P; back-project with the hard-render depth."""
    pts, cols = [], []
    for vi, (img, cam) in enumerate(zip(train.images, train.cameras)):
        prior = priors[vi] if priors is not None else None
        score, depth, _ = ivps_view_scores(g, cam, prior, rc, device, bg, near)
        n = min(int(round(rc.ivps_fraction * cam.width * cam.height)), int((score > 0).sum()))
        if n == 0:
            continue
        idx = rng.choice(score.size, size=n, replace=False, p=score / score.sum())
        pts.append(backproject_pixels(cam, idx, depth.ravel()[idx]))
        cols.append(np.asarray(img).reshape(-1, 3)[idx])
    if not pts:
        raise RuntimeError("IVPS: the coarse Gaussians cover no pixel of any training view")
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.float32)


def gaussian_importance(g, cameras, device, bg, near) -> np.ndarray:
    """Omega_G (Eq. 7): per Gaussian, the sum over `cameras` and their pixels of alpha*T where it
    blends; float64 [N]. The basis of CVPS and of the final prune (pass training cameras only)."""
    from .rendering import render

    omega = np.zeros(len(g), np.float64)
    for cam in cameras:
        omega += render(g, cam, device, bg, near, want_importance=True).importance
    return omega


def prune_keep_indices(omega, keep: float) -> np.ndarray:
    """Sorted indices of the round(keep * N) Gaussians (at least 1 when N > 0) of highest `omega`;
    deterministic: a stable sort of -omega, so ties keep the lower index."""
    omega = np.asarray(omega, np.float64)
    if not 0.0 < float(keep) <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep!r}")
    n = len(omega)
    k = min(n, max(1, int(round(float(keep) * n)))) if n else 0
    return np.sort(np.argsort(-omega, kind="stable")[:k])


def cvps_select(g, train, rc: ReInGSConfig, device, bg, near, rng):
    """CVPS (Eq. 7-8): Omega_G = sum over views and pixels of alpha*T per Gaussian; draw
    rc.cvps_fraction of them (the paper: 40%) without replacement with p ~ Omega_G (+ a tiny
    epsilon so zero-score Gaussians are possible)."""
    omega = gaussian_importance(g, train.cameras, device, bg, near)
    p = omega + 1e-12 * max(omega.max(), 1.0)
    n = max(1, int(round(rc.cvps_fraction * len(g))))
    return np.sort(rng.choice(len(g), size=n, replace=False, p=p / p.sum()))


PRUNE_CURVE_KEEP = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4)


def prune_curve_points(g, omega, test, device, bg, near, keeps=PRUNE_CURVE_KEEP) -> list:
    """Test PSNR/SSIM (no LPIPS) of `g` restricted to its top `keep` fraction by `omega`, per keep:
    [{"keep", "gaussians", "psnr", "ssim"}]. Reporting only: the test views rank nothing."""
    pts = []
    for keep in keeps:
        gk = g.subset(prune_keep_indices(omega, keep))
        m = _evaluate(gk, test, device, bg, near, None, with_lpips=False)
        pts.append({"keep": float(keep), "gaussians": len(gk), "psnr": m.get("psnr"), "ssim": m.get("ssim")})
    return pts
# }}}


def _config_for(method: str, iters: int, sh_degree: int):
    from .config import preset

    if method == "3dgs":
        base = preset("3dgs")
        base = replace(base, densify=replace(base.densify, densify_until=base.iterations // 2))
    else:
        base = preset("dngaussian")
    return replace(with_iterations(base, iters), sh_degree=sh_degree)


def _soft_stage_config(iters: int, sh_degree: int):
    """Fine and final ReInGS optimizations: DNGaussian's recipe with soft depth only (paper Eq. 9),
    no clean_views (their initial points come from the training views)."""
    c = _config_for("dngaussian", iters, sh_degree)
    return replace(c, loss=replace(c.loss, hard_depth=False), densify=replace(c.densify, clean_views=False))


def _evaluate(g, test, device, bg, near, out_dir=None, with_lpips=True):
    from .metrics import LPIPSModelNotFound, evaluate_images
    from .rendering import render

    preds, depths = [], []
    for cam in test.cameras:
        r = render(g, cam, device, bg, near)
        preds.append(np.clip(r.rgb, 0, 1))
        depths.append(r.depth / np.maximum(r.alpha, 1e-6))
    try:
        m = evaluate_images(preds, list(test.images), masks=test.masks, with_lpips=with_lpips)
    except LPIPSModelNotFound as e:  # no LPIPS model on this machine: report without it
        m = evaluate_images(preds, list(test.images), masks=test.masks, with_lpips=False)
        m["lpips_error"] = str(e)
    if out_dir:
        import cv2

        os.makedirs(os.path.join(out_dir, "renders"), exist_ok=True)
        os.makedirs(os.path.join(out_dir, "depths"), exist_ok=True)
        for name, p, d in zip(test.names, preds, depths):
            stem = os.path.splitext(os.path.basename(name))[0]
            cv2.imwrite(os.path.join(out_dir, "renders", stem + ".png"),
                        cv2.cvtColor((p * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))
            dn = (d - d.min()) / max(float(d.max() - d.min()), 1e-9)
            cv2.imwrite(os.path.join(out_dir, "depths", stem + ".png"), (dn * 65535).astype(np.uint16))
    return m


# {{{ method names, run settings, resume bookkeeping

def parse_method(name: str, reings_config: ReInGSConfig | None = None) -> tuple[str, ReInGSConfig]:
    """("reings" | "dngaussian" | "3dgs", ReInGSConfig) of a method name.

    Ablations are spelled as the base name plus switched-off strategies: "reings-no-ehps",
    "reings-no-ivps-no-cvps" (paper Table 4). They apply on top of `reings_config`."""
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"unknown method {name!r}: use {', '.join(METHODS)} (ablations: {', '.join(ABLATION_METHODS)})")
    rc = reings_config or ReInGSConfig()
    n = name.strip().lower()
    if n in QUICK_ITERS:
        return n, rc
    if n.startswith("reings-"):
        parts = n[len("reings-"):].split("-")
        off = []
        if len(parts) % 2 == 0 and all(a == "no" and b in ABLATIONS for a, b in zip(parts[::2], parts[1::2])):
            off = parts[1::2]
            if len(set(off)) == len(off):
                return "reings", replace(rc, **{k: False for k in off})
    raise ValueError(f"unknown method {name!r}: use {', '.join(METHODS)} or an ablation such as "
                     f"{', '.join(ABLATION_METHODS)} (combine: reings-no-ivps-no-cvps)")


def method_label(base: str, rc: ReInGSConfig) -> str:
    """The inverse of `parse_method`: "reings-no-ehps" etc. (base name for the baselines)."""
    if base != "reings":
        return base
    return "reings" + "".join(f"-no-{k}" for k in ABLATIONS if not getattr(rc, k))


def _iters_of(base: str, preset: str, iterations) -> tuple:
    if iterations is None:
        it = (QUICK_ITERS if preset == "quick" else PAPER_ITERS)[base]
    else:
        it = iterations
    if isinstance(it, (int, np.integer)):
        it = (int(it),) * (3 if base == "reings" else 1)
    it = tuple(int(i) for i in it)
    if base != "reings":
        it = it[-1:]
    if len(it) != (3 if base == "reings" else 1) or min(it) < 1:
        raise ValueError(f"iterations must be a positive count (reings: one count or three, per stage), got {iterations!r}")
    return it


def auto_eval_every(iters: int, points: int = 15) -> int:
    """Test-PSNR probes every this many iterations: about `points` per stage."""
    return max(1, int(round(iters / points)))


def gaussians_nbytes(g) -> int:
    """Bytes of the Gaussian parameters (means, quats, scales, opacities, SH) as held on the host."""
    return int(sum(np.asarray(getattr(g, f)).nbytes for f in ("means", "quats", "log_scales", "opacity_logits", "sh")))


def device_peak_bytes(backend) -> int | None:
    """High-water mark of the backend's device buffers in this process (None if not tracked)."""
    for obj in (backend, getattr(backend, "scratch", None)):
        v = getattr(obj, "peak_bytes", None) if obj is not None else None
        if v is not None:
            return int(v)
    return None


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return _jsonable(dataclasses.asdict(x))
    return x


def write_json_atomic(path: str, obj) -> None:
    """json.dump to `path` through a temp file in the same folder + rename (never half-written)."""
    from .io.files import atomic_write

    with atomic_write(path) as f:
        json.dump(_jsonable(obj), f, indent=1)


RUN_OUTPUTS = ("metrics.json", "psnr_vs_time.svg", "gaussians.ply")


def _prepare_out(out: str, settings: dict, overwrite: bool) -> None:
    """Refuse a finished run (unless overwrite), refuse checkpoints of other settings (unless
    overwrite); with overwrite, remove the previous run's outputs and checkpoints first."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    done = os.path.join(out, "metrics.json")
    ckdir = os.path.join(out, "checkpoints")
    run_json = os.path.join(ckdir, "run.json")
    if os.path.exists(done) and not overwrite:
        raise FileExistsError(f"{out} already holds a finished run (metrics.json); pass --overwrite to redo it")
    if os.path.exists(run_json) and not overwrite:
        try:
            with open(run_json) as f:
                old = json.load(f)
        except (OSError, ValueError):
            old = None
        if old is not None and old != _jsonable(settings):
            diff = sorted(k for k in set(old) | set(settings) if old.get(k) != _jsonable(settings).get(k))
            raise ValueError(f"{out} holds an interrupted run with other settings ({', '.join(diff)} differ); "
                             "pass --overwrite to start over, or another --out")
    if overwrite:
        for name in RUN_OUTPUTS:
            try:
                os.unlink(os.path.join(out, name))
            except FileNotFoundError:
                pass
        if os.path.isdir(ckdir):
            for name in os.listdir(ckdir):
                if name.endswith(".npz") or name == "run.json":
                    os.unlink(os.path.join(ckdir, name))
    os.makedirs(ckdir, exist_ok=True)
    write_json_atomic(run_json, settings)
# }}}


# {{{ test PSNR during training, speed-vs-error series and its SVG

def test_psnr(g, test, device, bg, near) -> float:
    """Mean per-image PSNR of the test views (DTU: masked), no LPIPS: the cheap probe."""
    from .metrics import psnr
    from .rendering import render

    vals = []
    for i, (cam, ref) in enumerate(zip(test.cameras, test.images)):
        r = render(g, cam, device, bg, near)
        m = None if test.masks is None else test.masks[i]
        vals.append(psnr(np.clip(r.rgb, 0, 1), ref, mask=m))
    return float(np.mean(vals))


def _svg_ticks(lo: float, hi: float, n: int = 6) -> list[float]:
    span = max(hi - lo, 1e-9)
    raw = span / max(n - 1, 1)
    mag = 10 ** np.floor(np.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=raw)
    first = np.ceil(lo / step) * step
    return [float(v) for v in np.arange(first, hi + step * 1e-6, step)]


def psnr_time_svg(points: list, bounds: list, title: str = "", width: int = 640, height: int = 400) -> str:
    """A small standalone SVG: test PSNR (dB) against training seconds, one polyline through the
    points, dashed lines at the stage boundaries, labelled stages. points: dicts with "seconds"
    and "psnr"; bounds: dicts with "stage", "start", "end" (seconds)."""
    from xml.sax.saxutils import escape

    ml, mr, mt, mb = 60, 20, 30 if title else 15, 45
    pw, ph = width - ml - mr, height - mt - mb
    xs = [float(p["seconds"]) for p in points] + [float(b["end"]) for b in bounds]
    ys = [float(p["psnr"]) for p in points if p.get("psnr") is not None]
    x0, x1 = 0.0, max(xs + [1e-3])
    y0, y1 = (min(ys), max(ys)) if ys else (0.0, 1.0)
    pad = max(0.5, 0.05 * (y1 - y0))
    y0, y1 = np.floor(y0 - pad), np.ceil(y1 + pad)
    X = lambda v: ml + (v - x0) / (x1 - x0) * pw  # noqa: E731
    Y = lambda v: mt + ph - (v - y0) / (y1 - y0) * ph  # noqa: E731
    o = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
         f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
         f'<rect x="0" y="0" width="{width}" height="{height}" fill="white"/>']
    if title:
        o.append(f'<text x="{width / 2:.1f}" y="18" text-anchor="middle" font-size="13">{escape(title)}</text>')
    for i, b in enumerate(bounds):  # stage bands: shaded alternately, boundary dashed, name on top
        xa, xb = X(float(b["start"])), X(float(b["end"]))
        if i % 2:
            o.append(f'<rect x="{xa:.1f}" y="{mt}" width="{max(xb - xa, 0):.1f}" height="{ph}" fill="#f2f2f2"/>')
        if i:
            o.append(f'<line x1="{xa:.1f}" y1="{mt}" x2="{xa:.1f}" y2="{mt + ph}" stroke="#888" stroke-dasharray="4,3"/>')
        o.append(f'<text x="{(xa + xb) / 2:.1f}" y="{mt + 12}" text-anchor="middle" fill="#555">{escape(str(b["stage"]))}</text>')
    for t in _svg_ticks(x0, x1):
        o.append(f'<line x1="{X(t):.1f}" y1="{mt + ph}" x2="{X(t):.1f}" y2="{mt + ph + 5}" stroke="black"/>')
        o.append(f'<text x="{X(t):.1f}" y="{mt + ph + 17}" text-anchor="middle">{t:g}</text>')
    for t in _svg_ticks(y0, y1):
        o.append(f'<line x1="{ml - 5}" y1="{Y(t):.1f}" x2="{ml}" y2="{Y(t):.1f}" stroke="black"/>')
        o.append(f'<line x1="{ml}" y1="{Y(t):.1f}" x2="{ml + pw}" y2="{Y(t):.1f}" stroke="#e4e4e4"/>')
        o.append(f'<text x="{ml - 8}" y="{Y(t) + 4:.1f}" text-anchor="end">{t:g}</text>')
    o.append(f'<rect x="{ml}" y="{mt}" width="{pw}" height="{ph}" fill="none" stroke="black"/>')
    o.append(f'<text x="{ml + pw / 2:.1f}" y="{height - 8}" text-anchor="middle">training seconds '
             '(wall clock, probes excluded)</text>')
    o.append(f'<text x="14" y="{mt + ph / 2:.1f}" text-anchor="middle" '
             f'transform="rotate(-90 14 {mt + ph / 2:.1f})">test PSNR (dB)</text>')
    pts = [(X(float(p["seconds"])), Y(float(p["psnr"]))) for p in points if p.get("psnr") is not None]
    if pts:
        o.append('<polyline fill="none" stroke="#1f77b4" stroke-width="1.8" points="'
                 + " ".join(f"{a:.1f},{b:.1f}" for a, b in pts) + '"/>')
        o.extend(f'<circle cx="{a:.1f}" cy="{b:.1f}" r="2.2" fill="#1f77b4"/>' for a, b in pts)
    o.append("</svg>")
    return "\n".join(o) + "\n"


def write_text_atomic(path: str, text: str) -> None:
    from .io.files import atomic_write

    with atomic_write(path) as f:
        f.write(text)
# }}}


def _rc_settings(rc: ReInGSConfig) -> dict:
    """ReInGSConfig as recorded in checkpoints/run.json. final_prune is left out when 0 (the value
    before the option existed), so that runs interrupted before then still resume."""
    d = dataclasses.asdict(rc)
    if not d.get("final_prune"):
        d.pop("final_prune", None)
    return d


def load_run_scene(data, dataset=None, factor=8):
    """`load_scene` for a run: LLFF's full-view COLMAP points are not read (the few-shot side
    never uses them, and reading them needs pycolmap, which a GPU machine may lack)."""
    from .data.scene import _ALIASES, detect_format, load_scene

    if data is None or str(data) == "procedural":
        return load_scene(data, dataset, factor=factor)
    kind = _ALIASES.get(str(dataset).lower(), str(dataset).lower()) if dataset else detect_format(os.fspath(data))
    kw = {"load_points": False} if kind in ("llff", "llff_nex") else {}
    return load_scene(data, dataset, factor=factor, **kw)


def run(data=None, dataset=None, method="reings", views=3, device="pocl", depth_prior="stereo",
        preset="quick", iterations=None, seed=0, out=None, overwrite=False, factor=8, quiet=False,
        reings_config: ReInGSConfig | None = None, init_points=5000, sh_degree=None,
        with_lpips=True, eval_every=None, checkpoint_every=250, max_gaussians=None,
        extent="sfm", prune_curve=False, depth_smooth=None) -> RunResult:
    """Fit one scene with `method` and evaluate its test views; see the module docstring.

    method: "reings", "dngaussian", "3dgs", or an ablation "reings-no-ehps" (also -no-ivps,
        -no-cvps, combinable), applied on top of `reings_config`.
    iterations: per stage (reings: one count for all three stages, or a 3-tuple); None = preset.
    eval_every: test-PSNR probe every this many iterations (None: about 15 per stage; 0: off).
    extent: "sfm" (the SfM box of the training views, falling back to their frusta) or "frusta"
        (the training-frusta box directly, no SfM) for EHPS and the random inits.
    max_gaussians: optional cap on the Gaussian count that densification respects in every stage
        (DensifyConfig.max_gaussians); None = no cap.
    depth_smooth: weight of DNGaussian's edge-aware depth smoothness in every stage's depth passes
        (LossConfig.depth_smooth_weight); None = the recipe's 0.1 (from the middle of each stage),
        except 0 with the stereo prior (no measured benefit there; see run's body).
    reings_config.final_prune: reings only; after the final stage, remove that fraction of the
        Gaussians with the lowest Omega_G over the training views (the reported model).
    prune_curve: also report test PSNR/SSIM of the final model cut to its top 100%, 90%, ..., 40%
        by the same Omega_G (metrics["prune_curve"]); a study tool, the test views rank nothing and
        the reported model is unchanged.
    out: output folder (None: nothing written, no resume). A folder holding metrics.json is refused
        unless overwrite=True (which starts over); one holding checkpoints of the same settings
        is resumed.
    """
    from .backends import get_backend
    from .data.depth_prior import get_depth_prior
    from .data.sfm import sfm_extent
    from .data.splits import few_shot_split
    from .io.ply import write_ply

    # -- validate everything a user can get wrong before anything is written
    base, rc = parse_method(method, reings_config)
    label = method_label(base, rc)
    if preset not in ("quick", "paper"):
        raise ValueError(f"unknown preset {preset!r}: use quick or paper")
    if extent not in ("sfm", "frusta"):
        raise ValueError(f"unknown extent {extent!r}: use sfm or frusta")
    if isinstance(views, bool) or not isinstance(views, (int, np.integer)) or views < 2:
        raise ValueError(f"views must be an integer >= 2 (the SfM box needs two training views), got {views!r}")
    its = _iters_of(base, preset, iterations)
    if eval_every is not None and (isinstance(eval_every, bool) or int(eval_every) < 0):
        raise ValueError(f"eval_every must be >= 0 (0 = off), got {eval_every!r}")
    if int(checkpoint_every) < 1:
        raise ValueError(f"checkpoint_every must be >= 1, got {checkpoint_every!r}")
    if depth_smooth is not None and (isinstance(depth_smooth, bool) or not np.isfinite(float(depth_smooth))
                                     or float(depth_smooth) < 0):
        raise ValueError(f"depth_smooth must be a finite weight >= 0, got {depth_smooth!r}")
    fp = rc.final_prune
    if isinstance(fp, bool) or not isinstance(fp, (int, float, np.integer, np.floating)) or not 0.0 <= float(fp) < 1.0:
        raise ValueError(f"final_prune must be a fraction in [0, 1) (0 = off), got {fp!r}")
    if data is not None and str(data) != "procedural":
        if not os.path.exists(os.fspath(data)):
            raise FileNotFoundError(f"--data {data}: scene folder not found")
        if not os.path.isdir(os.fspath(data)):
            raise NotADirectoryError(f"--data {data}: not a folder")
    if out and os.path.exists(os.path.join(out, "metrics.json")) and not overwrite:  # before any work
        raise FileExistsError(f"{out} already holds a finished run (metrics.json); pass --overwrite to redo it")
    backend = get_backend(device)  # unknown device -> DeviceNotFound, before anything is written
    prior = None if depth_prior == "exact" else get_depth_prior(depth_prior)
    t_start = time.perf_counter()
    timings, counts, model_bytes = {}, {}, {}

    t = time.perf_counter()
    scene = load_run_scene(data, dataset, factor=factor)
    tr_idx, te_idx = few_shot_split(scene, int(views))
    train, test = scene.subset(tr_idx), scene.subset(te_idx)  # training side sees only `train`
    if not len(test):
        raise ValueError(f"{data or 'procedural'}: the split leaves no test view")
    timings["load"] = time.perf_counter() - t
    if depth_prior == "exact" and train.depths is None:
        raise ValueError("--depth-prior exact needs a scene with exact depths (the procedural scene)")
    if sh_degree is None:
        # paper preset: SH 3 for the baselines (their recipes); SH 1 for reings, from the model-size
        # study (docs/results.md): -61% parameters per Gaussian, test PSNR -0.14..+0.37 dB (mean +0.07)
        sh_degree = 0 if preset == "quick" else (1 if base == "reings" else 3)
    scene_name = "procedural" if data is None or str(data) == "procedural" else os.path.basename(os.path.normpath(os.fspath(data)))
    settings = {
        "method": label, "data": None if data is None else os.path.abspath(os.fspath(data)),
        "dataset": scene.kind, "views": int(views), "preset": preset, "iterations": list(its),
        "seed": int(seed), "depth_prior": depth_prior, "factor": factor, "init_points": int(init_points),
        "sh_degree": int(sh_degree), "reings_config": _rc_settings(rc),
        "max_gaussians": None if not max_gaussians else int(max_gaussians), "extent": extent,
    }
    if depth_smooth is not None:  # absent = the preset's (older run folders resume unchanged)
        settings["depth_smooth"] = float(depth_smooth)
    if out:
        _prepare_out(out, settings, overwrite)
    # the depth smoothness weight of every stage: as given, else the recipe's (0.1) except with the
    # stereo prior, whose edges (holes filled by a guided filter) are not the mono network's edges
    # the term was designed for. With the stereo prior it had no measurable effect: 30 paired
    # full-schedule runs (fern and flower, 2/3/4 views, 5 methods; docs/results.md) moved test PSNR
    # by +0.01 dB on average when it was off (reings +0.11, dngaussian +0.14, per-run spread +-0.5)
    smooth_w = (float(depth_smooth) if depth_smooth is not None
                else 0.0 if depth_prior == "stereo" else None)  # None: the preset's
    rng = np.random.default_rng(seed)
    log = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    if rc.final_prune > 0 and base != "reings":
        log(f"[{label}] note: final_prune applies to reings only; ignored")

    t = time.perf_counter()
    if depth_prior == "exact":
        priors = list(train.depths)
    else:
        priors = prior.compute(train) if getattr(prior, "enabled", True) else None
        if priors is not None and all(p is None for p in priors):
            priors = None
    timings["depth_prior"] = time.perf_counter() - t

    t = time.perf_counter()
    if extent == "frusta":
        from .data.sfm import frusta_only_extent

        ext = frusta_only_extent(train)
    else:
        ext = sfm_extent(train)
    timings["sfm"] = time.perf_counter() - t
    bg, near = (0.0, 0.0, 0.0), 0.01
    progress = not quiet
    ck = (lambda name: os.path.join(out, "checkpoints", name + ".npz")) if out else (lambda name: None)
    extent = scene_extent(train.cameras)
    stages, series, bounds = [], [], []
    clock = {"train": 0.0, "wall": 0.0, "probe": 0.0}  # cumulative across stages

    def probe(g):
        t0 = time.perf_counter()
        v = test_psnr(g, test, device, bg, near)
        dt = time.perf_counter() - t0
        clock["probe"] += dt
        return {"psnr": v, "eval_seconds": dt}

    def between(name, seconds):  # re-initialisation work between two fits counts on the clock
        timings[name] = seconds
        clock["train"] += seconds
        clock["wall"] += seconds

    def stage_fit(name, cfg, init, use_priors):
        if max_gaussians:
            cfg = replace(cfg, densify=replace(cfg.densify, max_gaussians=int(max_gaussians)))
        if smooth_w is not None:
            cfg = replace(cfg, loss=replace(cfg.loss, depth_smooth_weight=smooth_w))
        ee = auto_eval_every(cfg.iterations) if eval_every is None else int(eval_every)
        if not series and ee:  # the starting point of the curve: the initial Gaussians
            series.append({"stage": "init", "iteration": 0, "seconds": 0.0, "wall_seconds": 0.0,
                           **probe(init)})
        r = fit(train, cfg, device=device, init=init, depth_targets=priors if use_priors else None,
                progress=progress, checkpoint=ck(name), checkpoint_every=int(checkpoint_every),
                eval_fn=probe if ee else None, eval_every=ee, desc=name, extent=extent)
        # history.eval: (iteration, seconds since this fit's start taken before the probe ran,
        # {"psnr", "eval_seconds"}); restored from the checkpoint on resume
        ev = [tuple(e) for e in r.history.eval]
        before, start = 0.0, dict(clock)
        for it, sec, m in ev:
            series.append({"stage": name, "iteration": int(it), "seconds": start["train"] + float(sec) - before,
                           "wall_seconds": start["wall"] + float(sec), "psnr": m.get("psnr"),
                           "eval_seconds": m.get("eval_seconds")})
            before += float(m.get("eval_seconds") or 0.0)
        train_s = max(float(r.seconds) - before, 0.0)
        clock["train"] += train_s
        clock["wall"] += float(r.seconds)
        bounds.append({"stage": name, "start": start["train"], "end": clock["train"]})
        timings[name] = train_s
        counts[name] = len(r.gaussians)
        model_bytes[name] = gaussians_nbytes(r.gaussians)
        stages.append({"stage": name, "iterations": cfg.iterations, "seconds": train_s,
                       "wall_seconds": float(r.seconds), "eval_seconds": before, "eval_every": ee,
                       "gaussians": len(r.gaussians), "model_bytes": model_bytes[name],
                       "peak_rss_mb": _peak_rss_mb(), "device_peak_bytes": device_peak_bytes(backend),
                       "config": cfg.to_dict(), "history": r.history.to_dict()})
        last = f", test PSNR {series[-1]['psnr']:.2f}" if series and series[-1]["stage"] == name else ""
        log(f"[{label}] {name}: {cfg.iterations} its, {train_s:.1f} s, {len(r.gaussians)} Gaussians{last}")
        return r.gaussians

    if base in ("3dgs", "dngaussian"):
        cfg = _config_for(base, its[0], sh_degree)
        init = gaussians_from_points(random_points_in_box(ext.lo, ext.hi, init_points, rng), None, sh_degree, rng)
        counts["init"] = len(init)
        model_bytes["init"] = gaussians_nbytes(init)
        g = stage_fit(base, cfg, init, base == "dngaussian")
    else:
        i1, i2, i3 = its
        base_cfg = _config_for("dngaussian", i1, sh_degree)
        if rc.ehps:
            init = ehps_init(ext.lo, ext.hi, rc, sh_degree, rng)
        else:
            init = gaussians_from_points(random_points_in_box(ext.lo, ext.hi, init_points, rng), None, sh_degree, rng)
        counts["init"] = len(init)
        model_bytes["init"] = gaussians_nbytes(init)
        coarse_cfg = replace(base_cfg, loss=replace(base_cfg.loss, hard_depth_opacity=rc.ivps_hard_opacity, soft_depth=False))
        g1 = stage_fit("coarse", coarse_cfg, init, True)
        t = time.perf_counter()
        if rc.ivps:
            pts, cols = ivps_points(g1, train, priors, rc, device, bg, near, rng)
            init2 = gaussians_from_points(pts, cols, sh_degree, rng)
        else:
            init2 = g1
        between("ivps", time.perf_counter() - t)
        counts["ivps"] = len(init2)
        g2 = stage_fit("fine", _soft_stage_config(i2, sh_degree), init2, True)
        t = time.perf_counter()
        if rc.cvps:
            sel = cvps_select(g2, train, rc, device, bg, near, rng)
            sh = g2.sh[sel].copy()
            sh[:, 1:] = 0  # keep the colour (DC), reset the view dependence
            init3 = dataclasses.replace(gaussians_from_points(g2.means[sel], None, sh_degree, rng), sh=sh)
        else:
            init3 = g2
        between("cvps", time.perf_counter() - t)
        counts["cvps"] = len(init3)
        g = stage_fit("final", _soft_stage_config(i3, sh_degree), init3, True)
    # final prune / prune curve: Omega_G of the final model over the TRAINING views. Computed here on
    # every (re)run from the final Gaussians (from final.npz on resume), never checkpointed: applied
    # exactly once, and deterministically (stable ranking, deterministic renders).
    g_final, omega, omega_s = g, None, 0.0
    do_prune = base == "reings" and rc.final_prune > 0
    if do_prune or prune_curve:
        t = time.perf_counter()
        omega = gaussian_importance(g_final, train.cameras, device, bg, near)
        omega_s = time.perf_counter() - t
    if do_prune:
        t = time.perf_counter()
        g = g_final.subset(prune_keep_indices(omega, 1.0 - float(rc.final_prune)))
        dt = omega_s + time.perf_counter() - t
        between("final_prune", dt)
        counts["final_prune"] = len(g)
        model_bytes["final_prune"] = gaussians_nbytes(g)
        stages.append({"stage": "final_prune", "iterations": 0, "seconds": dt, "wall_seconds": dt,
                       "eval_seconds": 0.0, "fraction": float(rc.final_prune), "gaussians_before": len(g_final),
                       "gaussians": len(g), "model_bytes": model_bytes["final_prune"],
                       "peak_rss_mb": _peak_rss_mb(), "device_peak_bytes": device_peak_bytes(backend),
                       "importance": "Omega_G (Eq. 7), alpha*T summed over the training views"})
        if series:  # the curve ends on the reported (pruned) model
            series.append({"stage": "final_prune", "iteration": 0, "seconds": clock["train"],
                           "wall_seconds": clock["wall"], **probe(g)})
        log(f"[{label}] final_prune: {len(g_final)} -> {len(g)} Gaussians "
            f"(lowest {rc.final_prune:.0%} by training-view Omega_G removed)")
    timings["method"] = clock["train"]  # training + re-initialisation, probes excluded
    timings["probes"] = clock["probe"]
    curve = None
    if prune_curve:  # reporting only: the final model (before final_prune) cut by the same ranking
        t = time.perf_counter()
        curve = prune_curve_points(g_final, omega, test, device, bg, near)
        timings["prune_curve"] = time.perf_counter() - t + (0.0 if do_prune else omega_s)

    t = time.perf_counter()
    m = _evaluate(g, test, device, bg, near, out, with_lpips=with_lpips)
    timings["eval"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    dev_peak = device_peak_bytes(backend)
    metrics = {
        "method": label, "base_method": base, "scene": scene_name, "dataset": scene.kind,
        "preset": preset, "views": int(views), "device": device,
        "device_name": getattr(backend, "device_name", device),
        "data": data or "procedural", "train_indices": list(map(int, tr_idx)), "test_indices": list(map(int, te_idx)),
        "train_names": list(train.names), "test_names": list(test.names), "depth_prior": depth_prior,
        "seed": seed, "sh_degree": sh_degree,
        "mean": {k: m[k] for k in ("psnr", "ssim", "lpips", "avge") if k in m and m[k] is not None},
        "per_image": m.get("per_image"), "seconds": timings, "gaussians": counts,
        "model_bytes": model_bytes,
        "peak_rss_mb": _peak_rss_mb(),
        "memory": {"peak_rss_mb": _peak_rss_mb(), "device_peak_mb": None if dev_peak is None else dev_peak / 2**20,
                   "device_peak_bytes": dev_peak, "model_mb": {k: v / 2**20 for k, v in model_bytes.items()},
                   "note": "peaks are this process's high-water marks (several runs in one process share them)"},
        "sfm": {"method": ext.method, "points": int(ext.num_sfm_points), "lo": ext.lo, "hi": ext.hi,
                "cached": bool(getattr(ext, "cached", False)), "note": getattr(ext, "note", "")},
        "psnr_vs_time": {"points": series, "stages": bounds,
                         "clock": "seconds = training + re-initialisation wall clock, test-PSNR probes excluded; "
                                  "wall_seconds = the same with the probes"},
        "reings_config": dataclasses.asdict(rc), "config": {**settings, "device": device, "with_lpips": with_lpips,
                                                            "eval_every": eval_every, "checkpoint_every": checkpoint_every,
                                                            "prune_curve": bool(prune_curve)},
        "stages": stages,
    }
    if curve is not None:
        metrics["prune_curve"] = curve
    if "lpips_error" in m:
        metrics["lpips_error"] = m["lpips_error"]
    metrics = _jsonable(metrics)
    if out:
        write_ply(os.path.join(out, "gaussians.ply"), g)
        if series:
            write_text_atomic(os.path.join(out, "psnr_vs_time.svg"),
                              psnr_time_svg(series, bounds, f"{label} on {scene_name}, {views} views ({device})"))
        write_json_atomic(os.path.join(out, "metrics.json"), metrics)  # last: marks the run finished
    return RunResult(g, metrics, stages)


def main_run(args) -> int:
    rc = ReInGSConfig(ehps=not args.no_ehps, ivps=not args.no_ivps, cvps=not args.no_cvps,
                      ivps_depth=args.ivps_depth, cvps_fraction=args.cvps_fraction,
                      final_prune=getattr(args, "final_prune", ReInGSConfig.final_prune))
    r = run(data=args.data, dataset=args.dataset, method=args.method, views=args.views, device=args.device,
            depth_prior=args.depth_prior, preset=args.preset, iterations=args.iterations, seed=args.seed,
            out=args.out, overwrite=args.overwrite, factor=args.factor, quiet=args.quiet, reings_config=rc,
            eval_every=args.eval_every, with_lpips=not args.no_lpips, init_points=args.init_points,
            sh_degree=args.sh_degree, max_gaussians=args.max_gaussians, extent=args.extent,
            prune_curve=getattr(args, "prune_curve", False), depth_smooth=getattr(args, "depth_smooth", None))
    m = r.metrics
    mean = m["mean"]
    print(f"{m['method']} on {m['data']} ({m['views']} views, {m['device']}): "
          + " ".join(f"{k.upper()} {v:.4f}" for k, v in mean.items())
          + f" | {m['seconds']['method']:.1f} s training ({m['seconds']['total']:.1f} s total)"
          + f" | Gaussians {m['gaussians']} | {args.out}")
    return 0
