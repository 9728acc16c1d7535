"""`reings run` / `reings.run`: one scene, end to end.

    data -> few-shot split (training side gets ONLY the training views) -> depth prior ->
    method stages -> test-view evaluation -> outputs

Methods:
    3dgs        random init, 3DGS losses, no depth terms
    dngaussian  random init, DNGaussian recipe (hard + soft depth)
    reings      EHPS -> coarse (photometric + hard depth) -> IVPS -> fine (+ soft depth)
                -> CVPS -> final (+ soft depth)   (paper Eq. 4-9; METHOD.md §1)

Outputs in --out: `gaussians.ply`, `renders/<name>.png`, `depths/<name>.png`, `metrics.json`
(per image and mean PSNR/SSIM/LPIPS/AVGE, seconds per stage, Gaussian counts, peak memory,
device, config), `checkpoints/` (resume after an interruption).
"""
from __future__ import annotations

import dataclasses
import json
import os
import resource
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .train import fit, gaussians_from_points, random_points_in_box, scene_extent, with_iterations

QUICK_ITERS = {"3dgs": 600, "dngaussian": 600, "reings": (200, 200, 600)}
PAPER_ITERS = {"3dgs": 6000, "dngaussian": 6000, "reings": (6000, 6000, 6000)}


@dataclass
class ReInGSConfig:
    """ReInGS re-initialisation settings (paper §3; METHOD.md §1.3-1.5). Defaults = the paper /
    METHOD.md proposals."""

    gamma: float = 1.4  # EHPS: expansion of the SfM box about its centre
    beta1: float = 200.0  # EHPS: uniform grid points = beta1 * max side of the expanded box
    beta2: float = 50.0  # EHPS: random points = beta2 * max side of the expanded box
    min_init_points: int = 2000  # EHPS: floor on the total (scenes in small units)
    delta: float = 0.03  # IVPS: weight of the depth-consistency score
    ivps_fraction: float = 0.10  # IVPS: fraction of pixels sampled per training view
    ivps_hard_opacity: float = 0.99  # IVPS: forced opacity of the depth render (Eq. 5)
    ivps_min_alpha: float = 0.5  # IVPS: pixels with hard alpha below this get score 0
    cvps_fraction: float = 0.40  # CVPS: fraction of Gaussians kept
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


def ivps_points(g, train, priors, rc: ReInGSConfig, device, bg, near, rng):
    """IVPS (Eq. 4-6): per view, Omega_P = delta*Omega_D + (1-delta)*Omega_T; draw ~10% of the
    pixels without replacement with p ~ Omega_P; back-project with the hard-render depth."""
    from .rendering import render

    pts, cols = [], []
    for vi, (img, cam) in enumerate(zip(train.images, train.cameras)):
        hard = render(g, cam, device, bg, near, opacity_override=rc.ivps_hard_opacity)
        soft = render(g, cam, device, bg, near)
        valid = hard.alpha >= rc.ivps_min_alpha
        depth = np.where(valid, hard.depth / np.maximum(hard.alpha, 1e-6), 0.0)
        omega_t = soft.final_T if soft.final_T is not None else 1.0 - soft.alpha
        omega_d = np.zeros_like(depth)
        if priors is not None and priors[vi] is not None and valid.sum() > 16:
            e = np.abs(_zscore(depth, valid) - _zscore(np.asarray(priors[vi], np.float64), valid))
            ev = e[valid]
            omega_d = 1.0 - (e - ev.min()) / max(ev.max() - ev.min(), 1e-12)
        score = rc.delta * omega_d + (1 - rc.delta) * omega_t
        score = np.where(valid, np.maximum(score, 1e-6), 0.0).ravel()
        n = min(int(round(rc.ivps_fraction * cam.width * cam.height)), int((score > 0).sum()))
        if n == 0:
            continue
        idx = rng.choice(score.size, size=n, replace=False, p=score / score.sum())
        v, u = np.divmod(idx, cam.width)
        z = depth.ravel()[idx]
        x = (u + 0.5 - cam.cx) / cam.fx * z
        y = (v + 0.5 - cam.cy) / cam.fy * z
        Xc = np.stack([x, y, z], 1)
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        pts.append((Xc - t) @ R)  # R^T (Xc - t)
        cols.append(np.asarray(img).reshape(-1, 3)[idx])
    if not pts:
        raise RuntimeError("IVPS: the coarse Gaussians cover no pixel of any training view")
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.float32)


def cvps_select(g, train, rc: ReInGSConfig, device, bg, near, rng):
    """CVPS (Eq. 7-8): Omega_G = sum over views and pixels of alpha*T per Gaussian; draw 40%
    without replacement with p ~ Omega_G (+ a tiny epsilon so zero-score Gaussians are possible)."""
    from .rendering import render

    omega = np.zeros(len(g), np.float64)
    for cam in train.cameras:
        omega += render(g, cam, device, bg, near, want_importance=True).importance
    p = omega + 1e-12 * max(omega.max(), 1.0)
    n = max(1, int(round(rc.cvps_fraction * len(g))))
    return np.sort(rng.choice(len(g), size=n, replace=False, p=p / p.sum()))
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


def run(data=None, dataset=None, method="reings", views=3, device="pocl", depth_prior="stereo",
        preset="quick", iterations=None, seed=0, out=None, overwrite=False, factor=8, quiet=False,
        reings_config: ReInGSConfig | None = None, init_points=5000, sh_degree=None,
        with_lpips=True) -> RunResult:
    """Fit one scene with `method` and evaluate its test views; see the module docstring."""
    from .data.depth_prior import get_depth_prior
    from .data.procedural import make_procedural_scene
    from .data.scene import load_scene
    from .data.sfm import sfm_extent
    from .data.splits import few_shot_split
    from .io.ply import write_ply

    if method not in QUICK_ITERS:
        raise ValueError(f"unknown method {method!r}: use reings, dngaussian or 3dgs")
    if preset not in ("quick", "paper"):
        raise ValueError(f"unknown preset {preset!r}: use quick or paper")
    if out:
        done = os.path.join(out, "metrics.json")
        if os.path.exists(done) and not overwrite:
            raise FileExistsError(f"{out} already holds a finished run (metrics.json); pass --overwrite")
        os.makedirs(os.path.join(out, "checkpoints"), exist_ok=True)
    rc = reings_config or ReInGSConfig()
    rng = np.random.default_rng(seed)
    t_start = time.perf_counter()
    timings, counts = {}, {}

    t = time.perf_counter()
    scene = make_procedural_scene() if data is None else load_scene(data, dataset, factor=factor)
    tr_idx, te_idx = few_shot_split(scene, views)
    train, test = scene.subset(tr_idx), scene.subset(te_idx)  # training side sees only `train`
    timings["load"] = time.perf_counter() - t
    if sh_degree is None:
        sh_degree = 0 if preset == "quick" else 3

    t = time.perf_counter()
    if depth_prior == "exact":
        if train.depths is None:
            raise ValueError("--depth-prior exact needs a scene with exact depths (the procedural scene)")
        priors = list(train.depths)
    else:
        prior = get_depth_prior(depth_prior)
        priors = prior.compute(train) if getattr(prior, "enabled", True) else None
        if priors is not None and all(p is None for p in priors):
            priors = None
    timings["depth_prior"] = time.perf_counter() - t

    t = time.perf_counter()
    ext = sfm_extent(train)
    timings["sfm"] = time.perf_counter() - t
    bg, near = (0.0, 0.0, 0.0), 0.01
    progress = not quiet
    ck = (lambda name: os.path.join(out, "checkpoints", name + ".npz")) if out else (lambda name: None)
    extent = scene_extent(train.cameras)
    stages = []

    def stage_fit(name, cfg, init, use_priors):
        t0 = time.perf_counter()
        r = fit(train, cfg, device=device, init=init, depth_targets=priors if use_priors else None,
                progress=progress, checkpoint=ck(name), desc=name, extent=extent)
        timings[name] = time.perf_counter() - t0
        counts[name] = len(r.gaussians)
        stages.append({"stage": name, "seconds": timings[name], "gaussians": len(r.gaussians),
                       "history": r.history.to_dict()})
        return r.gaussians

    iters = iterations or (QUICK_ITERS if preset == "quick" else PAPER_ITERS)[method]
    if method in ("3dgs", "dngaussian"):
        cfg = _config_for(method, iters if isinstance(iters, int) else iters[-1], sh_degree)
        init = gaussians_from_points(random_points_in_box(ext.lo, ext.hi, init_points, rng), None, sh_degree, rng)
        counts["init"] = len(init)
        g = stage_fit(method, cfg, init, method == "dngaussian")
    else:
        i1, i2, i3 = (iters, iters, iters) if isinstance(iters, int) else iters
        base = _config_for("dngaussian", i1, sh_degree)
        if rc.ehps:
            init = ehps_init(ext.lo, ext.hi, rc, sh_degree, rng)
        else:
            init = gaussians_from_points(random_points_in_box(ext.lo, ext.hi, init_points, rng), None, sh_degree, rng)
        counts["init"] = len(init)
        coarse_cfg = replace(base, loss=replace(base.loss, hard_depth_opacity=rc.ivps_hard_opacity, soft_depth=False))
        g1 = stage_fit("coarse", coarse_cfg, init, True)
        t = time.perf_counter()
        if rc.ivps:
            pts, cols = ivps_points(g1, train, priors, rc, device, bg, near, rng)
            init2 = gaussians_from_points(pts, cols, sh_degree, rng)
        else:
            init2 = g1
        timings["ivps"] = time.perf_counter() - t
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
        timings["cvps"] = time.perf_counter() - t
        counts["cvps"] = len(init3)
        g = stage_fit("final", _soft_stage_config(i3, sh_degree), init3, True)

    t = time.perf_counter()
    m = _evaluate(g, test, device, bg, near, out, with_lpips=with_lpips)
    timings["eval"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    from .backends import get_backend

    metrics = {
        "method": method, "preset": preset, "views": views, "device": device,
        "device_name": getattr(get_backend(device), "device_name", device),
        "data": data or "procedural", "train_indices": list(map(int, tr_idx)), "test_indices": list(map(int, te_idx)),
        "test_names": list(test.names), "depth_prior": depth_prior, "seed": seed, "sh_degree": sh_degree,
        "mean": {k: m[k] for k in ("psnr", "ssim", "lpips", "avge") if k in m and m[k] is not None},
        "per_image": m.get("per_image"), "seconds": timings, "gaussians": counts,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "sfm": {"method": ext.method, "points": int(ext.num_sfm_points)},
        "reings_config": rc.__dict__, "stages": stages,
    }
    if "lpips_error" in m:
        metrics["lpips_error"] = m["lpips_error"]
    if out:
        write_ply(os.path.join(out, "gaussians.ply"), g)
        tmp = os.path.join(out, "metrics.json.tmp")
        with open(tmp, "w") as f:
            json.dump(metrics, f, indent=1, default=float)
        os.replace(tmp, os.path.join(out, "metrics.json"))
    return RunResult(g, metrics, stages)


def main_run(args) -> int:
    r = run(data=args.data, dataset=args.dataset, method=args.method, views=args.views, device=args.device,
            depth_prior=args.depth_prior, preset=args.preset, iterations=args.iterations, seed=args.seed,
            out=args.out, overwrite=args.overwrite, factor=args.factor, quiet=args.quiet)
    m = r.metrics
    mean = m["mean"]
    print(f"{m['method']} on {m['data']} ({m['views']} views, {m['device']}): "
          + " ".join(f"{k.upper()} {v:.4f}" for k, v in mean.items())
          + f" | {m['seconds']['total']:.1f} s | Gaussians {m['gaussians']} | {args.out}")
    return 0
