"""`reings process PHOTOS_DIR --out SCENE_DIR`: unposed photos to a COLMAP scene `reings run` reads.

Steps (COLMAP through pycolmap, on the CPU; reings.data.colmap.map_photos / undistort_model):
SIFT features with one SIMPLE_RADIAL camera shared by every photo (`per_image_camera` for photos
from different cameras), exhaustive matching with geometric verification, incremental mapping,
then undistortion to PINHOLE cameras. The scene folder gets

    images/        the undistorted photos
    sparse/0/      the PINHOLE model (cameras, images, points3D)
    process.json   what happened: registered photos, the ones left out and why, the camera

The folder appears whole or not at all: everything is built in a temporary folder beside it and
renamed at the end; an existing scene is replaced only with `overwrite`, and only once the new one
is complete. A photo that does not register is an error naming it and the reason, unless
`partial` is set (then the scene holds the registered photos and process.json names the others).
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time

from .types import SceneError


def suggested_factor(width: int, target: int = 1000) -> int:
    """The downsampling factor that brings `width` to at most about `target` pixels."""
    return max(1, -(-int(width) // int(target)))


def process_photos(photos_dir, out_dir, overwrite: bool = False, partial: bool = False,
                   per_image_camera: bool = False, quiet: bool = False) -> dict:
    """Run the steps (module docstring); returns the process.json summary."""
    from . import colmap
    from .images import list_images

    photos_dir, out_dir = os.fspath(photos_dir), os.fspath(out_dir)
    if not out_dir:
        raise ValueError("--out must name a folder")
    real_out, real_photos = os.path.realpath(out_dir), os.path.realpath(photos_dir)
    if os.path.commonpath([real_out, real_photos]) == real_out:  # the scene would replace the photos
        raise ValueError(f"--out {out_dir}: is or holds the photos folder {photos_dir}, which the scene would "
                         "replace; write the scene to another folder")
    names = list_images(photos_dir)
    if len(names) < 2:
        raise SceneError(f"{photos_dir}: {len(names)} photo; structure from motion needs at least 2")
    if os.path.exists(out_dir):
        if not os.path.isdir(out_dir):
            raise NotADirectoryError(f"--out {out_dir}: exists and is not a folder")
        if os.listdir(out_dir) and not overwrite:
            raise FileExistsError(f"--out {out_dir}: folder is not empty; pass --overwrite to replace it")
    parent = os.path.dirname(os.path.abspath(out_dir))
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".tmp-process-", dir=parent)
    bar = None
    try:
        from ..log import progress_enabled

        if progress_enabled(quiet):
            from tqdm import tqdm

            bar = tqdm(total=4, desc="process", leave=False, file=sys.stderr, dynamic_ncols=True)

        def step(name):
            if bar is not None:
                bar.set_postfix_str(name)
                if name != "features":
                    bar.update(1)

        t0 = time.perf_counter()
        work = os.path.join(tmp, "colmap")
        os.makedirs(work)
        rec, model_dir, missing = colmap.map_photos(photos_dir, names, work, single_camera=not per_image_camera,
                                                    step=step)
        kept = [n for n in names if n not in missing]
        if len(kept) < 2:
            raise SceneError(f"{photos_dir}: only {len(kept)} photo registered: "
                             + "; ".join(f"{n}: {why}" for n, why in missing.items()))
        if missing and not partial:
            raise SceneError(f"{photos_dir}: {len(missing)} of {len(names)} photos did not register: "
                             + "; ".join(f"{n}: {why}" for n, why in missing.items())
                             + " (pass --partial to make the scene from the others)")
        step("undistort")
        colmap.undistort_model(model_dir, photos_dir, tmp, kept)
        os.makedirs(os.path.join(tmp, "sparse", "0"))
        for f in os.listdir(os.path.join(tmp, "sparse")):
            if f != "0":
                os.replace(os.path.join(tmp, "sparse", f), os.path.join(tmp, "sparse", "0", f))
        for junk in ("stereo", "colmap"):
            shutil.rmtree(os.path.join(tmp, junk), ignore_errors=True)
        for f in os.listdir(tmp):
            if f.startswith("run-colmap-"):
                os.unlink(os.path.join(tmp, f))
        if bar is not None:
            bar.update(1)
        summary = _summary(tmp, photos_dir, names, kept, missing, time.perf_counter() - t0)
        with open(os.path.join(tmp, "process.json"), "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=1)
        _swap_in(tmp, out_dir)
        return summary
    finally:
        if bar is not None:
            bar.close()
        if os.path.isdir(tmp):
            shutil.rmtree(tmp, ignore_errors=True)


def _summary(folder, photos_dir, names, kept, missing, seconds) -> dict:
    """process.json, with the model read back as `reings run` will read it."""
    from .colmap import load_colmap_scene

    scene = load_colmap_scene(folder, factor=1)
    cam = scene.cameras[0]
    import pycolmap

    return {"photos": os.path.abspath(photos_dir), "photos_given": len(names), "registered": kept,
            "left_out": missing, "points": 0 if scene.points is None else int(len(scene.points)),
            "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                       "cy": cam.cy, "model": "PINHOLE (undistorted)"},
            "suggested_factor": suggested_factor(cam.width), "seconds": seconds,
            "pycolmap": getattr(pycolmap, "__version__", "?")}


def _swap_in(tmp: str, out_dir: str) -> None:
    """Put the finished scene at `out_dir`; a scene already there goes only once the new one is in."""
    if os.path.isdir(out_dir):
        old = tempfile.mkdtemp(prefix=".tmp-previous-", dir=os.path.dirname(os.path.abspath(out_dir)))
        os.rmdir(old)
        os.replace(out_dir, old)
        try:
            os.replace(tmp, out_dir)
        except BaseException:
            os.replace(old, out_dir)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out_dir)


def main_process(args) -> int:
    s = process_photos(args.photos, args.out, overwrite=args.overwrite, partial=args.partial,
                       per_image_camera=args.per_image_camera, quiet=args.quiet)
    c = s["camera"]
    left = f"; left out: {', '.join(s['left_out'])}" if s["left_out"] else ""
    print(f"registered {len(s['registered'])} of {s['photos_given']} photos, {s['points']} points, "
          f"PINHOLE {c['width']}x{c['height']} fx {c['fx']:.1f} in {s['seconds']:.1f} s{left} -> {args.out}")
    print(f"next: reings run --data {args.out} --holdout none --factor {s['suggested_factor']} --out RUN_DIR")
    return 0
