"""`reings eval`: every scene x view count x method of a dataset, then a results table.

    reings eval --dataset llff --root data/llff --views 2,3,4 --methods reings,dngaussian \
        --device cuda:0 --preset paper --out runs/llff_paper

Each run is `reings.pipeline.run(RunConfig)` into its own folder
`OUT/<dataset>/<method>/<k>views/<scene>/` (`<scene>_seed<s>/` for a seed s other than 0: with
`--seeds 0,1,2` every cell of the table is the mean over seeds, with its min-max). The run options
(`reings run`'s, generated from `reings.config.RunConfig`, or `--config run.toml`) apply to every
run; eval sets the method, views, seed, data and folder of each. A run whose folder holds
`metrics.json` is finished and skipped; one holding checkpoints is resumed. A run being worked on holds an exclusive lock (`fcntl.flock`, on Windows `msvcrt.locking`, on
`<run>/.lock`, freed when its process ends however it ends; reings/io/lock.py): a guard, so that
no run is ever trained twice at once (a Dask task retried while its first worker still runs, or a
second `reings eval` started on the same OUT): several `reings eval` processes with the same
arguments share the work (each skips the runs another holds; docs/pipeline.md), but `--cluster`
(reings/cluster.py, docs/cluster.md) is the way to share a grid between devices or machines: a
scheduler, retries of dead workers, one progress view, and no reliance on `flock` over a network
filesystem.

After the runs (or alone, with `--table-only`) the table is rebuilt from every `metrics.json`
under OUT: `OUT/results.json` and `OUT/results.md` in the paper's layout (rows = methods,
columns = PSNR/SSIM/LPIPS/AVGE x view count; mean over scenes, then per scene), with the
paper's printed numbers beside ours (`PAPER`, each row citing its table).

`--prepare-only` fills the depth-prior and SfM caches for every scene x view count without
training (copy $REINGS_CACHE_DIR to a machine without pycolmap).
"""
from __future__ import annotations

import datetime
import json
import os
import sys
import time

import numpy as np

from .io.lock import RunLock  # the per-run lock (also reings.cluster's)

METRICS = ("psnr", "ssim", "lpips", "avge")
ARROW = {"psnr": "↑", "ssim": "↑", "lpips": "↓", "avge": "↓"}

# {{{ the paper's numbers (docs/method.md §6: the ReInGS paper's Tables 2-4), only as printed there
# Table 2: LLFF, 2/3/4 views, rows "without sparsity discrepancy" (random init, as our runs).
# Table 3: DTU, 3 views, rows without sparsity discrepancy.
# Table 4: LLFF, 3 views ablations (PSNR, LPIPS, SSIM only; no AVGE). The check marks of Table 4
# are garbled in the text extraction; the row -> switches mapping below follows §4.2 ("EHPS, then
# IVPS, then CVPS: +0.49, +0.41, +1.09 dB"; "Rows 5 and 6: VDPS (IVPS+CVPS) alone ... adding
# EHPS"), and row 1 (18.87) is the reproduced DNGaussian baseline, equal to Table 2's.


def _row(psnr, ssim, lpips, avge=None):
    return {"psnr": psnr, "ssim": ssim, "lpips": lpips, **({"avge": avge} if avge is not None else {})}


PAPER = {
    "llff": [
        {"method": "reings", "name": "ReInGS (paper)", "source": "paper Table 2", "views": {
            2: _row(19.39, 0.599, 0.296, 0.132), 3: _row(20.88, 0.687, 0.256, 0.108), 4: _row(22.24, 0.748, 0.239, 0.092)}},
        {"method": "dngaussian", "name": "DNGaussian ✗SD (paper)", "source": "paper Table 2", "views": {
            2: _row(16.47, 0.450, 0.408, 0.192), 3: _row(18.87, 0.583, 0.313, 0.141), 4: _row(20.86, 0.690, 0.266, 0.107)}},
        {"method": "3dgs", "name": "3DGS ✗SD (paper)", "source": "paper Table 2", "views": {
            2: _row(12.83, 0.311, 0.470, 0.273), 3: _row(14.99, 0.483, 0.362, 0.202), 4: _row(17.31, 0.584, 0.297, 0.153)}},
        {"method": "reings-no-ivps-no-cvps", "name": "EHPS only (paper)", "source": "paper Table 4 row 2",
         "views": {3: _row(19.38, 0.589, 0.348)}},
        {"method": "reings-no-cvps", "name": "EHPS+IVPS (paper)", "source": "paper Table 4 row 3",
         "views": {3: _row(19.79, 0.645, 0.260)}},
        {"method": "reings-no-ivps", "name": "EHPS+CVPS (paper)", "source": "paper Table 4 row 4",
         "views": {3: _row(20.05, 0.611, 0.314)}},
        {"method": "reings-no-ehps", "name": "IVPS+CVPS (paper)", "source": "paper Table 4 row 5",
         "views": {3: _row(19.66, 0.638, 0.285)}},
    ],
    "dtu": [
        {"method": "reings", "name": "ReInGS (paper)", "source": "paper Table 3", "views": {3: _row(21.30, 0.832, 0.170, 0.081)}},
        {"method": "dngaussian", "name": "DNGaussian ✗SD (paper)", "source": "paper Table 3",
         "views": {3: _row(18.85, 0.763, 0.227, 0.116)}},
        {"method": "3dgs", "name": "3DGS ✗SD (paper)", "source": "paper Table 3", "views": {3: _row(12.77, 0.681, 0.278, 0.167)}},
    ],
}
PAPER_NOTE = ("Paper numbers: the ReInGS paper (Tables 2-4, copied in docs/method.md §6), as printed; ✗SD = the paper's rows without "
              "sparsity discrepancy (random initial points, as these runs). Table 4 (ablations, LLFF 3 views) "
              "prints no AVGE, and its row-to-switch mapping is read from §4.2 (the extracted check marks are "
              "ambiguous). DTU numbers for 2 and 4 views are in the paper's appendix Table 5, not available here.")
_FAMILY = {"llff_nex": "llff", "colmap": "llff"}  # protocol family for the paper columns
PAPER_SCENES = {"llff": 8, "dtu": 15}  # the paper's means are over the whole benchmark
# }}}


class EvalError(ValueError):
    """A user-facing `reings eval` error."""


def parse_list(text, what: str, cast=str) -> list:
    if text is None:
        return []
    items = [t.strip() for t in str(text).split(",") if t.strip()]
    if not items:
        raise EvalError(f"--{what}: empty list")
    out = []
    for t in items:
        try:
            v = cast(t)
        except ValueError:
            raise EvalError(f"--{what}: bad entry {t!r}") from None
        if v not in out:
            out.append(v)
    return out


def discover_scenes(root: str, dataset: str | None) -> list[tuple[str, str]]:
    """(name, kind) of every scene folder directly under `root` whose format is detected (and, with
    `dataset`, belongs to it); folders that are not scenes (DTU's masks/, ...) are skipped."""
    from .data.loader import detect_format
    from .data.types import SceneError

    found = []
    for name in sorted(os.listdir(root)):
        p = os.path.join(root, name)
        if name.startswith(".") or not os.path.isdir(p):
            continue
        try:
            kind = detect_format(p)
        except SceneError:
            continue
        if dataset is None or kind == dataset or _FAMILY.get(kind) == dataset:
            found.append((name, kind))
    return found


def run_dir(out: str, dataset: str, method: str, views: int, scene: str, seed: int = 0) -> str:
    """OUT/<dataset>/<method>/<k>views/<scene>, and <scene>_seed<s> for seeds other than 0."""
    return os.path.join(out, dataset, method, f"{views}views", scene if not seed else f"{scene}_seed{seed}")


# {{{ table

def _setting_tag(m: dict) -> str:
    """What distinguishes two runs of the same method beyond scene, views and seed (seeds are
    replicates: one cell shows their mean and spread): preset, iteration override, depth prior,
    smoothness, final prune."""
    from .config import RUN_PRESETS, ReInGSConfig

    cfg = m.get("config") or {}
    preset = m.get("preset", cfg.get("preset", "?"))
    tag = [str(preset)]
    base = m.get("base_method") or str(m.get("method", "")).split("-")[0]
    its = cfg.get("iterations")
    p = RUN_PRESETS.get(preset)
    default = list(p.iterations[base]) if p is not None and base in p.iterations else None
    if its is not None and default is not None and list(its) != default:
        tag.append("its " + ("/".join(map(str, its)) if len(set(its)) > 1 else str(its[0])))
    if m.get("depth_prior", "stereo") != "stereo":
        tag.append(f"prior {m['depth_prior']}")
    if cfg.get("depth_smooth") is not None:
        tag.append(f"smooth {cfg['depth_smooth']:g}")
    if cfg.get("view_warp"):
        tag.append(f"warp {cfg['view_warp']:g}/{cfg.get('view_warp_disparity', 4.0):g}px"
                   + (f" from {cfg['view_warp_start']:.3g}" if cfg.get("view_warp_start") is not None else "")
                   + (f" every {cfg['view_warp_every']}" if cfg.get("view_warp_every") else "")
                   + (f" at 1/{cfg['view_warp_scale']}" if cfg.get("view_warp_scale") else ""))
    if cfg.get("opacity_decay") not in (None, 1):
        tag.append(f"decay {cfg['opacity_decay']:g}")
    if cfg.get("drop_gamma"):  # DropGaussian (absent when off)
        tag.append(f"drop {cfg['drop_gamma']:g}")
    if cfg.get("depth_metric"):  # the metric depth term (absent when off)
        tag.append(f"metric {cfg['depth_metric']:g}")
    if cfg.get("cross_warp"):  # the cross-view photometric term (absent when off)
        tag.append(f"cross {cfg['cross_warp']:g}" + (f" from {cfg['cross_warp_start']:g}"
                                                      if cfg.get("cross_warp_start") else "")
                   + (f" occl {cfg['cross_warp_occlusion']:g}" if cfg.get("cross_warp_occlusion") else "")
                   + (" blur " + ",".join(f"{v:g}" for v in cfg["cross_warp_blur"]) if cfg.get("cross_warp_blur")
                      else ""))
    if cfg.get("prune_unseen"):  # absent when off
        tag.append("prune unseen")
    if cfg.get("off_frame_margin") is not None:  # the off-frame prune (absent when off)
        tag.append(f"off-frame {cfg['off_frame_margin']:g}")
    if cfg.get("near_prune") is not None:  # the near prune (absent when off)
        tag.append(f"near prune {cfg['near_prune']:g}")
    if cfg.get("max_screen_fraction"):  # the screen-size prune (absent when off)
        tag.append(f"screen prune {cfg['max_screen_fraction']:g}")
    if cfg.get("fit_scale"):  # the fits' resolution divisors (absent when all 1)
        tag.append("scale " + "/".join(map(str, cfg["fit_scale"]))
                   + (" share " + "/".join(f"{v:g}" for v in cfg["fit_scale_share"])
                      if cfg.get("fit_scale_share") else ""))
    lam = cfg.get("lambda_dssim")  # --lambda-dssim (absent: the recipe's SSIM weight; a list: per stage)
    if lam is not None:
        tag.append("ssim " + ("/".join(f"{v:g}" for v in lam) if isinstance(lam, list) else f"{lam:g}"))
    if cfg.get("grad_threshold_scale") is not None:  # absent at 1
        tag.append(f"grad x{cfg['grad_threshold_scale']:g}")
    if cfg.get("soft_depth_shared"):  # absent when off
        tag.append("soft shared")
    if cfg.get("ensemble"):  # absent for one model
        tag.append(f"ensemble {cfg['ensemble']}" + (f" from {cfg['ensemble_from']}"
                                                   if cfg.get("ensemble_from") not in (None, "init") else ""))
    seeds = (cfg.get("reings_config") or {}).get("stereo_seeds")  # absent: none (the preset's or the auto rule)
    if base == "reings" and seeds is not None:
        tag.append(f"seeds {seeds:g}")
    fp = (cfg.get("reings_config") or {}).get("final_prune")  # absent: a run from before the option
    if base == "reings" and fp is not None and fp != ReInGSConfig.final_prune:
        tag.append(f"prune {fp:g}")
    return ", ".join(tag)


def collect_runs(out: str) -> list[dict]:
    """Every finished run (metrics.json) and unfinished run folder (checkpoints/) under `out`."""
    runs = []
    for dirpath, dirnames, filenames in os.walk(out):
        dirnames[:] = sorted(d for d in dirnames if d not in ("checkpoints", "renders", "depths") and not d.startswith("."))
        rel = os.path.relpath(dirpath, out)
        if "metrics.json" in filenames:
            try:
                with open(os.path.join(dirpath, "metrics.json")) as f:
                    m = json.load(f)
                if not isinstance(m, dict) or "mean" not in m:
                    raise ValueError("no 'mean'")
            except (OSError, ValueError) as e:
                runs.append({"path": rel, "status": "unreadable", "error": str(e)})
                continue
            runs.append({"path": rel, "status": "done", "metrics": m})
            dirnames[:] = []
        elif os.path.isdir(os.path.join(dirpath, "checkpoints")):
            runs.append({"path": rel, "status": "unfinished"})
            dirnames[:] = []
    return runs


def _scene_of(m: dict, path: str) -> str:
    if m.get("scene"):
        return str(m["scene"])
    d = m.get("data") or "procedural"
    return os.path.basename(os.path.normpath(str(d))) or os.path.basename(path)


def _dataset_of(m: dict, path: str) -> str:
    parts = path.split(os.sep)
    if len(parts) >= 4:  # OUT/<dataset>/<method>/<k>views/<scene>
        return parts[-4]
    return str(m.get("dataset") or "unknown")


def _run_entry(m: dict, path: str) -> dict:
    sec = m.get("seconds") or {}
    entry = {k: m["mean"].get(k) for k in METRICS}
    entry.update({"seconds": sec.get("method", sec.get("total")), "seconds_total": sec.get("total"),
                  "gaussians": ((m["ensemble"].get("gaussians") if isinstance(m.get("ensemble"), dict) else None)
                                or ((m.get("stages") or [{}])[-1].get("gaussians") if m.get("stages") else None)),
                  "device": m.get("device"), "device_name": m.get("device_name"), "run": path,
                  "seed": int(m.get("seed") or 0)})
    return entry


def _mean(xs):
    xs = [x for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def _scene_over_seeds(by_seed: dict) -> dict:
    """One scene's entry: the run's (one seed), or the mean over seeds with `seeds`, `runs`, and
    per metric `spread` [min, max] and `std` (ddof 1)."""
    seeds = sorted(by_seed)
    if len(seeds) == 1:
        return by_seed[seeds[0]]
    first = by_seed[seeds[0]]
    e = {k: _mean([by_seed[s].get(k) for s in seeds]) for k in METRICS + ("seconds", "seconds_total", "gaussians")}
    e.update({"device": first.get("device"), "device_name": first.get("device_name"), "run": first["run"],
              "seeds": seeds, "runs": {str(s): by_seed[s]["run"] for s in seeds}})
    e["spread"], e["std"] = {}, {}
    for k in METRICS:
        vals = [by_seed[s][k] for s in seeds if by_seed[s].get(k) is not None]
        if len(vals) > 1:
            e["spread"][k] = [float(min(vals)), float(max(vals))]
            e["std"][k] = float(np.std(vals, ddof=1))
    return e


def _cell(per_scene_seed: dict, n_all: int) -> tuple[dict, dict]:
    """A table cell (one method, setting, view count): the mean over scenes of each scene's mean over
    seeds; with several seeds also, per metric, the min-max (`spread`) and std (ddof 1) over seeds of
    the mean over the scenes that seed covers. Returns (cell, {scene: its entry})."""
    scenes = {s: _scene_over_seeds(by_seed) for s, by_seed in per_scene_seed.items()}
    cell = {k: _mean([e.get(k) for e in scenes.values()]) for k in METRICS + ("seconds", "gaussians")}
    seeds = sorted({seed for by_seed in per_scene_seed.values() for seed in by_seed})
    cell.update({"n_scenes": len(scenes), "complete": len(scenes) >= n_all, "seeds": seeds})
    if len(seeds) > 1:
        cell["spread"], cell["std"] = {}, {}
        for k in METRICS:
            per_seed = [_mean([by_seed[s].get(k) for by_seed in per_scene_seed.values() if s in by_seed]) for s in seeds]
            per_seed = [v for v in per_seed if v is not None]
            if len(per_seed) > 1:
                cell["spread"][k] = [float(min(per_seed)), float(max(per_seed))]
                cell["std"][k] = float(np.std(per_seed, ddof=1))
    return cell, scenes


def build_table(out: str, expected_scenes: dict | None = None) -> dict:
    """results.json content from the runs under `out`. expected_scenes: {dataset: [scene, ...]}
    (the denominator of "complete"; default: every scene seen in that dataset)."""
    runs = collect_runs(out)
    datasets: dict = {}
    for r in runs:
        if r["status"] != "done":
            continue
        m = r["metrics"]
        ds = _dataset_of(m, r["path"])
        d = datasets.setdefault(ds, {"views": set(), "scenes": set(), "groups": {}})
        views, scene = int(m.get("views", 0)), _scene_of(m, r["path"])
        d["views"].add(views)
        d["scenes"].add(scene)
        entry = _run_entry(m, r["path"])
        g = d["groups"].setdefault((str(m.get("method", "?")), _setting_tag(m)), {})
        g.setdefault(views, {}).setdefault(scene, {})[entry["seed"]] = entry
    result = {"generated": datetime.datetime.now().isoformat(timespec="seconds"), "out": os.path.abspath(out),
              "paper_note": PAPER_NOTE, "datasets": {},
              "runs": [{k: v for k, v in r.items() if k != "metrics"} for r in runs]}
    for ds, d in sorted(datasets.items()):
        scenes_all = sorted(set(d["scenes"]) | set((expected_scenes or {}).get(ds, [])))
        n_tags = {}
        for (method, _) in d["groups"]:
            n_tags[method] = n_tags.get(method, 0) + 1
        methods = {}
        for (method, tag), by_views in sorted(d["groups"].items(), key=lambda kv: (_method_order(kv[0][0]), kv[0][1])):
            mean, scenes = {}, {}
            for v, per_scene in sorted(by_views.items()):
                mean[v], per = _cell(per_scene, len(scenes_all))
                for s, e in per.items():
                    scenes.setdefault(s, {})[v] = e
            name = method if n_tags[method] == 1 else f"{method} [{tag}]"
            methods[name] = {"method": method, "setting": tag, "mean": mean,
                             "scenes": {s: scenes[s] for s in sorted(scenes)}}
        result["datasets"][ds] = {"views": sorted(d["views"]), "scenes": scenes_all,
                                  "settings": sorted({t for (_, t) in d["groups"]}), "methods": methods,
                                  "paper": list(PAPER.get(_FAMILY.get(ds, ds), []))}
    return result


def _method_order(method: str):
    from .config import METHODS

    base = method.split("-")[0]
    return (METHODS.index(base) if base in METHODS else 99, method)


def _fmt(v, k) -> str:
    if v is None:
        return "–"
    return f"{v:.2f}" if k == "psnr" else f"{v:.3f}"


def _fmt_spread(e: dict, k: str) -> str:
    """The value, and its min-max over seeds in brackets when there are several."""
    s = _fmt(e.get(k), k)
    lo_hi = (e.get("spread") or {}).get(k)
    return s + (f" [{_fmt(lo_hi[0], k)}–{_fmt(lo_hi[1], k)}]" if lo_hi else "")


def _header(views: list, first: str = "Method") -> list[str]:
    cols = [first] + [f"{k.upper()}{ARROW[k]} {v}v" for k in METRICS for v in views]
    return ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]


def _mean_rows(d: dict, cols: list) -> list[str]:
    """The mean table's rows: ours, each followed by the paper's row of the same method."""
    lines, shown_paper = [], set()
    for name, mth in d["methods"].items():
        cells = [name + " (ours)"]
        for k in METRICS:
            for v in cols:
                e = mth["mean"].get(v)
                if e is None:
                    cells.append("")
                    continue
                s = _fmt_spread(e, k)
                if not e["complete"]:
                    s += f" ({e['n_scenes']}/{len(d['scenes'])})"
                cells.append(s)
        lines.append("| " + " | ".join(cells) + " |")
        for i, p in enumerate(d["paper"]):
            if p["method"] == mth["method"] and i not in shown_paper:
                shown_paper.add(i)
                lines.append(_paper_line(p, cols))
    for i, p in enumerate(d["paper"]):  # paper rows of methods not run: listed at the end
        if i not in shown_paper and any(v in cols for v in p["views"]):
            lines.append(_paper_line(p, cols))
    return lines


def _cost_rows(d: dict, cols: list) -> list[str]:
    lines = ["| Method | " + " | ".join(f"{v}v seconds | {v}v Gaussians" for v in cols) + " | devices |",
             "|" + "---|" * (2 + 2 * len(cols))]
    for name, mth in d["methods"].items():
        cells = [name]
        for v in cols:
            e = mth["mean"].get(v) or {}
            cells += [("–" if e.get("seconds") is None else f"{e['seconds']:.1f}"),
                      ("–" if e.get("gaussians") is None else f"{e['gaussians']:.0f}")]
        devs = sorted({str(x.get("device_name") or x.get("device")) for pv in mth["scenes"].values() for x in pv.values()})
        cells.append(", ".join(devs))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _dataset_section(ds: str, d: dict) -> list[str]:
    views = d["views"]
    paper_views = sorted({v for p in d["paper"] for v in p["views"]})
    cols = sorted(set(views) | ({v for v in paper_views if v in views} if views else set()))
    lines = [f"## {ds.upper()}: mean over {len(d['scenes'])} scene(s) ({', '.join(d['scenes'])})", ""]
    if len(d["settings"]) > 1:
        per = "; ".join(f"{name}: {m['setting']}" for name, m in d["methods"].items())
        lines += [f"Settings differ between rows ({per}).", ""]
    elif d["settings"]:
        lines += [f"Setting: {d['settings'][0]}.", ""]
    seeds = sorted({s for m in d["methods"].values() for e in m["mean"].values() for s in e.get("seeds", [])})
    if len(seeds) > 1:
        lines += [f"Seeds {', '.join(map(str, seeds))}: each value is the mean over seeds, [min–max] the range "
                  "over seeds of the mean over scenes (per scene: of that scene's runs).", ""]
    n_paper = PAPER_SCENES.get(_FAMILY.get(ds, ds))
    if n_paper and d["paper"] and len(d["scenes"]) != n_paper:
        lines += [f"The paper's means are over all {n_paper} {ds.upper()} scenes, ours over "
                  f"{len(d['scenes'])}: compare per scene with care.", ""]
    lines += _header(cols) + _mean_rows(d, cols)
    lines += ["", "Seconds and final Gaussian counts (mean over scenes):", ""] + _cost_rows(d, cols)
    lines += ["", f"### {ds.upper()}: per scene", ""] + _header(cols, "Scene / method")
    for s in d["scenes"]:
        for name, mth in d["methods"].items():
            per = mth["scenes"].get(s)
            if per:
                cells = [f"{s} / {name}"] + [_fmt_spread(per[v], k) if v in per else "" for k in METRICS for v in cols]
                lines.append("| " + " | ".join(cells) + " |")
    return lines + [""]


def render_markdown(res: dict) -> str:
    lines = ["# Results", "",
             f"Generated {res['generated']} from the runs under `{res['out']}` by `reings eval --table-only`.",
             "Means are over scenes of each scene's mean over its test views. A mean marked `(k/n)` covers k of "
             "the n scenes only. Seconds = training + re-initialisation wall clock (probes excluded).", ""]
    for ds, d in res["datasets"].items():
        lines += _dataset_section(ds, d)
    unfinished = [r["path"] for r in res["runs"] if r["status"] != "done"]
    if unfinished:
        lines += ["Unfinished or unreadable run folders: " + ", ".join(f"`{p}`" for p in unfinished), ""]
    lines += [PAPER_NOTE, ""]
    return "\n".join(lines)


def _paper_line(p: dict, cols: list) -> str:
    cells = [f"{p['name']}, {p['source']}"]
    for k in METRICS:
        for v in cols:
            e = p["views"].get(v)
            cells.append("" if e is None or k not in e else _fmt(e[k], k))
    return "| " + " | ".join(cells) + " |"


def write_tables(out: str, expected_scenes: dict | None = None) -> dict:
    from .outputs import write_json_atomic, write_text_atomic

    res = build_table(out, expected_scenes)
    write_json_atomic(os.path.join(out, "results.json"), res)
    write_text_atomic(os.path.join(out, "results.md"), render_markdown(res))
    return res
# }}}


# {{{ the runs

def plan(args, base) -> tuple[list, dict]:
    """Validate the eval arguments; return (jobs, expected scenes per dataset) with jobs =
    [(dataset, scene, RunConfig of that run, its folder set as output.out)]: every scene x view
    count x method x seed, from `base` (the run options)."""
    from dataclasses import replace

    from .config import run_config

    views = parse_list(args.views, "views", int) or [base.views]
    bad = [v for v in views if v < 2]
    if bad:
        raise EvalError(f"--views: every count must be >= 2, got {bad}")
    seeds = parse_list(args.seeds, "seeds", int) or [base.seed]
    bad = [s for s in seeds if s < 0]
    if bad:
        raise EvalError(f"--seeds: every seed must be >= 0, got {bad}")
    methods = {}  # label -> config with that method (ablations on top of the base switches)
    for name in parse_list(args.methods, "methods") or [base.label]:
        c = run_config(base, method=name)
        methods.setdefault(c.label, c)
    dataset = base.dataset
    if dataset == "procedural" and args.root is None:
        scenes = [("procedural", "procedural", None)]
    else:
        if args.root is None:
            raise EvalError("--root is required (the folder of scene folders), except with --dataset procedural")
        if not os.path.isdir(args.root):
            raise EvalError(f"--root {args.root}: folder not found")
        found = discover_scenes(args.root, dataset)
        if args.scenes:
            want = parse_list(args.scenes, "scenes")
            kinds = dict(found)
            missing = [s for s in want if s not in kinds]
            if missing:
                raise EvalError(f"--scenes: no {dataset or ''} scene folder {', '.join(missing)} under {args.root} "
                                f"(found: {', '.join(kinds) or 'none'})")
            found = [(s, kinds[s]) for s in want]
        if not found:
            raise EvalError(f"--root {args.root}: no {dataset or ''} scene folders found")
        scenes = [(s, k, os.path.join(args.root, s)) for s, k in found]
    jobs, expected = [], {}
    for s, kind, path in scenes:
        ds = dataset or kind
        expected.setdefault(ds, []).append(s)
        for v in views:
            for lab, c in methods.items():
                for seed in seeds:
                    rd = run_dir(args.out, ds, lab, v, s, seed)
                    cfg = run_config(c, data=path, dataset=None if path is None else dataset, views=v, seed=seed)
                    jobs.append((ds, s, replace(cfg, output=replace(cfg.output, out=rd))))
    return jobs, expected


def _prepare(jobs) -> None:
    """Fill the depth-prior and SfM caches (no training)."""
    from .data.depth_prior import get_depth_prior
    from .data.sfm import sfm_extent
    from .data.splits import few_shot_split
    from .pipeline import load_run_scene, prior_for_family, recipe_family

    seen, priors = set(), {}
    for ds, s, cfg in jobs:
        key = (s, cfg.data, cfg.views, cfg.factor, cfg.depth_prior)
        if key in seen:
            continue
        seen.add(key)
        if cfg.depth_prior not in priors:
            priors[cfg.depth_prior] = None if cfg.depth_prior == "exact" else get_depth_prior(cfg.depth_prior)
        prior = priors[cfg.depth_prior]
        t = time.perf_counter()
        scene = load_run_scene(cfg.data, cfg.dataset, factor=cfg.factor)
        tr, _ = few_shot_split(scene, cfg.views)
        train = scene.subset(tr)
        if prior is not None and getattr(prior, "enabled", True):
            prior_for_family(prior, recipe_family(cfg.recipe, scene.kind)).compute(train)
        ext = sfm_extent(train)
        print(f"prepared {ds}/{s} {cfg.views} views: sfm {ext.method} ({ext.num_sfm_points} points"
              f"{', cached' if ext.cached else ''}), {time.perf_counter() - t:.1f} s", flush=True)


# settings recorded only when on (absent = off; view_warp_start: absent = 2/3; view_warp_every: absent = 1;
# lambda_dssim: absent = the recipe's): a run that has one and a config that has not differ
_ABSENT_WHEN_OFF = ("drop_gamma", "depth_metric", "prune_unseen", "cross_warp", "cross_warp_start",
                    "cross_warp_occlusion", "cross_warp_blur", "view_warp_start", "lambda_dssim",
                    "soft_depth_shared", "grad_threshold_scale", "ensemble", "ensemble_from", "hard_depth_scale",
                    "hard_depth_patches", "view_warp_every", "fit_scale", "fit_scale_share", "max_screen_fraction",
                    "off_frame_margin", "near_prune",
                    "view_warp_scale")


def _settings_differ(metrics_path: str, cfg, dataset_kind: str | None = None) -> str:
    """'' if the finished run at `metrics_path` has the settings `cfg` asks for (the keys both
    record, and those of _ABSENT_WHEN_OFF on either side, except the data path and format: folders
    move between machines). dataset_kind: the grid's dataset ("dtu" resolves the DTU recipe
    family's defaults)."""
    from .pipeline import run_settings

    try:
        with open(metrics_path) as f:
            have = json.load(f).get("config") or {}
        want = json.loads(json.dumps(run_settings(cfg.resolved(), dataset_kind)))
        keys = [k for k in want if k in have and k not in ("data", "dataset")]
        keys += [k for k in _ABSENT_WHEN_OFF if (k in have) != (k in want)]
        return ", ".join(f"{k} {have.get(k)!r} != {want.get(k)!r}" for k in keys if have.get(k) != want.get(k))
    except (OSError, ValueError, KeyError, AttributeError):
        return ""


def _run_one(i: int, n: int, ds: str, scene: str, cfg, args, say) -> str | None:
    """One job under its lock: 'busy' if another process holds it, else None (done, skipped or
    run). Exceptions propagate."""
    from . import pipeline

    rd = cfg.output.out
    seed = f" seed {cfg.seed}" if cfg.seed else ""
    head = f"[{i}/{n}] {ds} {scene} {cfg.views} views {cfg.label}{seed}"
    if os.path.exists(os.path.join(rd, "metrics.json")):
        diff = _settings_differ(os.path.join(rd, "metrics.json"), cfg, ds)
        if diff:
            print(f"{head}: WARNING: finished earlier with other settings ({diff}); kept, not redone "
                  "(remove the folder or use another --out)", file=sys.stderr, flush=True)
        say(f"{head}: done already ({rd})")
        return None
    lock = RunLock(rd)
    if not lock.acquire():
        say(f"{head}: held by another process, skipped")
        return "busy"
    try:
        if os.path.exists(os.path.join(rd, "metrics.json")):  # finished while we waited for the lock
            return None
        resumed = os.path.isdir(os.path.join(rd, "checkpoints"))
        say(f"{head}: {'resuming' if resumed else 'running'} on {cfg.device} -> {rd}")
        t = time.perf_counter()
        mm = pipeline.run(cfg, quiet=args.quiet).metrics["mean"]
        say(f"{head}: " + " ".join(f"{k.upper()} {mm[k]:.3f}" for k in METRICS if k in mm)
            + f" ({time.perf_counter() - t:.0f} s)")
    except Exception as e:
        print(f"{head}: FAILED: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        raise
    finally:
        lock.release()
    return None


def main_eval(args, base) -> int:
    """`reings eval` with its own options in `args` and the run options in `base` (a RunConfig)."""
    from .backends import get_backend

    out = args.out
    if os.path.exists(out) and not os.path.isdir(out):
        raise EvalError(f"--out {out} exists and is not a folder")
    if args.table_only:
        if not os.path.isdir(out):
            raise EvalError(f"--out {out}: folder not found (nothing to tabulate)")
        res = write_tables(out)
        n = sum(r["status"] == "done" for r in res["runs"])
        print(f"{n} finished run(s) -> {os.path.join(out, 'results.md')}, results.json")
        return 0
    if base.holdout != "protocol":
        raise EvalError("reings eval scores held-out views by the datasets' protocols; --holdout none is for "
                        "reings run (training on every view of your own photos)")
    jobs, expected = plan(args, base)
    if args.prepare_only:
        _prepare(jobs)
        return 0
    cluster = getattr(args, "cluster", None)
    rpg = getattr(args, "runs_per_gpu", 1)
    if rpg != 1 and not (cluster and cluster.startswith("local")):
        raise EvalError(f"--runs-per-gpu {rpg}: only with --cluster local[:N] (workers of an existing scheduler "
                        "are started with `reings worker --runs K`)")
    if rpg < 1:
        raise EvalError(f"--runs-per-gpu {rpg}: needs K >= 1")
    if cluster:
        from .cluster import parse_spec

        parse_spec(cluster)  # a bad spec: error before any folder is made
    if not cluster or cluster.startswith("local"):
        get_backend(base.device)  # unknown device: error before any folder is made
    os.makedirs(out, exist_ok=True)
    failed, busy = [], 0
    say = lambda msg: print(msg, flush=True)  # noqa: E731 - one line per run even with --quiet (bars off)
    if cluster:
        from .cluster import connect, run_grid

        with connect(cluster, base.device, getattr(args, "runs_per_gpu", 1)) as client:
            failed = run_grid(client, jobs, gpu_only=getattr(args, "gpu_only", False), quiet=args.quiet, say=say)
        jobs = []  # all submitted
    for i, (ds, s, cfg) in enumerate(jobs, 1):
        try:
            busy += _run_one(i, len(jobs), ds, s, cfg, args, say) == "busy"
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as e:
            failed.append((cfg.output.out, f"{type(e).__name__}: {e}"))
            if not args.keep_going:
                write_tables(out, expected)
                raise
    res = write_tables(out, expected)
    n = sum(r["status"] == "done" for r in res["runs"])
    print(f"{n} finished run(s) in {out}; table: {os.path.join(out, 'results.md')}"
          + (f"; {busy} held by other processes" if busy else ""))
    if failed:
        print(f"reings: error: {len(failed)} run(s) failed: " + "; ".join(f"{p}: {e}" for p, e in failed), file=sys.stderr)
        return 1
    return 0
# }}}
