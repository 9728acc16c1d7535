"""`reings export`: a finished run's model in the layouts viewers and 3DGS tools read.

    ply    OUT/point_cloud.ply: the 3DGS vertex layout (reings.io.ply), SH padded to `sh_degree`
           (3 by default: older SuperSplat, SIBR and several loaders assume 0 or 3 bands)
    inria  the output folder of the 3DGS reference code (graphdeco-inria/gaussian-splatting), which
           SIBR's gaussian viewer and the tools written for it open:
               OUT/point_cloud/iteration_<N>/point_cloud.ply   N = the run's total fit iterations
               OUT/cameras.json                                the run's cameras (reings.io.cameras)
               OUT/cfg_args                                    argparse.Namespace(...) as 3DGS writes it

Every PLY carries provenance comments in its header (`comment reings ...`: version, run folder,
method, scene, views, seed; for an ensemble run, that the file is member 0). Files are written whole or not at all; an existing file is replaced
only with `overwrite`.
"""
from __future__ import annotations

import json
import os

FORMATS = ("ply", "inria")


def _provenance(run_dir: str, metrics: dict) -> list[str]:
    from . import __version__

    def clean(v) -> str:
        return "".join(ch if ch.isascii() and ch.isprintable() else "?" for ch in str(v))

    lines = [f"reings {__version__} export of {clean(os.path.abspath(run_dir))}"]
    keys = ("method", "scene", "dataset", "views", "seed", "preset", "device_name")
    lines.append("reings run: " + " ".join(f"{k}={clean(metrics[k])}" for k in keys if k in metrics))
    mean = metrics.get("mean") or {}
    if mean:
        lines.append("reings scores (" + clean(metrics.get("scored_on", "test")) + " views): "
                     + " ".join(f"{k}={v:.4f}" for k, v in mean.items() if isinstance(v, (int, float))))
    ens = metrics.get("ensemble")
    if isinstance(ens, dict) and ens.get("members"):  # the scores above are the members' mean image's
        per = ens.get("per_member")
        p0 = per[0].get("psnr") if isinstance(per, list) and per and isinstance(per[0], dict) else None
        lines.append(f"reings ensemble of {clean(ens['members'])} models: this file is member 0 (gaussians.ply)"
                     + (f", psnr={p0:.4f} alone" if isinstance(p0, (int, float)) else "")
                     + "; the scores above are the members' mean image's")
    return lines


def _total_iterations(metrics: dict) -> int:
    its = (metrics.get("run_config") or {}).get("iterations")
    if isinstance(its, (list, tuple)) and its and all(isinstance(i, int) for i in its):
        return int(sum(its))
    return 30_000  # 3DGS's default, when the run does not say


def _check_free(paths, overwrite: bool) -> None:
    taken = [p for p in paths if os.path.lexists(p)]
    if taken and not overwrite:
        raise FileExistsError(f"{taken[0]} exists; pass --overwrite to replace it")
    for p in taken:
        if os.path.isdir(p) and not os.path.islink(p):
            raise IsADirectoryError(f"{p} is a folder; cannot replace it with a file")


def export_run(run_dir, out, format: str = "ply", sh_degree: int = 3, overwrite: bool = False) -> list[str]:  # noqa: A002
    """Write the run in `run_dir` to folder `out` in `format` ('ply' or 'inria'); returns the
    paths written."""
    from .io.cameras import read_cameras_json
    from .io.files import atomic_write
    from .io.ply import pad_sh, write_ply
    from .video import load_run

    if format not in FORMATS:
        raise ValueError(f"--format {format!r}: one of {', '.join(FORMATS)}")
    if isinstance(sh_degree, bool) or not isinstance(sh_degree, int) or not 0 <= sh_degree <= 3:
        raise ValueError(f"--sh-degree must be 0, 1, 2 or 3, got {sh_degree!r}")
    run_dir, out = os.fspath(run_dir), os.fspath(out)
    if not out:
        raise ValueError("--out must name a folder")
    g, _ = load_run(run_dir)
    from .io.files import read_json

    mpath = os.path.join(run_dir, "metrics.json")
    metrics = read_json(mpath, f"{run_dir}: no metrics.json (not a finished run)")
    if not isinstance(metrics, dict):
        raise ValueError(f"{mpath}: expected a JSON object")
    if os.path.exists(out) and not os.path.isdir(out):
        raise NotADirectoryError(f"--out {out}: exists and is not a folder")
    gp = pad_sh(g, sh_degree)
    comments = _provenance(run_dir, metrics)
    if format == "ply":
        ply = os.path.join(out, "point_cloud.ply")
        _check_free([ply], overwrite)
        os.makedirs(out, exist_ok=True)
        write_ply(ply, gp, comments)
        return [ply]
    it = _total_iterations(metrics)
    ply = os.path.join(out, "point_cloud", f"iteration_{it}", "point_cloud.ply")
    cams, cfg_args = os.path.join(out, "cameras.json"), os.path.join(out, "cfg_args")
    _check_free([ply, cams, cfg_args], overwrite)
    recs = read_cameras_json(os.path.join(run_dir, "cameras.json"))  # validated before anything is written
    os.makedirs(os.path.dirname(ply), exist_ok=True)
    write_ply(ply, gp, comments)
    from .io.cameras import camera_entry

    entries = [camera_entry(i, r.name, r.camera, r.split) for i, r in enumerate(recs)]
    with atomic_write(cams) as f:
        f.write(json.dumps(entries, indent=1) + "\n")
    data = metrics.get("data", "")
    src = os.path.abspath(data) if data and os.path.isdir(str(data)) else ""
    ns = (f"Namespace(data_device='cuda', eval={metrics.get('holdout', 'protocol') != 'none'}, images='images', "
          f"model_path={os.path.abspath(out)!r}, resolution=-1, sh_degree={sh_degree}, source_path={src!r}, "
          f"white_background=False)")
    with atomic_write(cfg_args) as f:
        f.write(ns)
    return [ply, cams, cfg_args]
