#!/usr/bin/env python3
"""Re-score finished DTU runs from their 8-bit test renders with the DTU protocol of
reings.metrics (masks resized by Pillow's bicubic filter, PSNR over the pixels whose mask is
exactly 1, SSIM and LPIPS composited over white with the soft mask: DNGaussian / CoR-GS
`metrics_dtu.py`), and print it beside the rule used before 2026-11-25 (masks area-resized,
foreground = mask > 0.5).

    python scripts/rescore_dtu.py RUNS_DIR [--data-root DIR] [--write]

RUNS_DIR: a run folder or a folder of them (every `metrics.json` below it whose dataset is dtu).
`--data-root` replaces the folder part of the run's `data` path that does not exist here.
`--write` stores the new PSNR/SSIM (and LPIPS where it was there) in metrics.json, the old values
under `mean_before_mask_rule`.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np


def _png(path: str) -> np.ndarray:
    from reings.data.images import read_image

    return read_image(path)


def _area_masks(scene, idx):
    """The rule before: the channel max of the full-size mask, area-resized, > 0.5."""
    from reings.data import dtu, images

    folder = dtu._mask_folder(scene.source)
    names = images.list_images(folder)
    out = []
    for i in idx:
        m = images.read_mask(os.path.join(folder, names[i]))
        h, w = scene.images[i].shape[:2]
        out.append(images.resize(m[:, :, None], w, h)[:, :, 0] > 0.5)
    return out


def rescore(run_dir: str, data_root: str | None, write: bool) -> dict | None:
    from reings import load_scene, metrics

    mpath = os.path.join(run_dir, "metrics.json")
    m = json.load(open(mpath))
    if m.get("dataset") != "dtu":
        return None
    data = m["data"]
    if not os.path.isdir(data) and data_root:
        data = os.path.join(data_root, os.path.basename(os.path.normpath(data)))
    scene = load_scene(data, dataset="dtu")
    idx, names = m["test_indices"], m["test_names"]
    preds = [_png(os.path.join(run_dir, "renders", n)) for n in names]
    refs = [scene.images[i] for i in idx]
    old_masks = _area_masks(scene, idx)
    new = metrics.evaluate_images(preds, refs, [scene.masks[i] for i in idx], with_lpips=False)
    old = metrics.evaluate_images(preds, refs, old_masks, with_lpips=False)
    row = {"run": run_dir, "recorded": m["mean"].get("psnr"), "psnr_before_rule": old["psnr"],
           "psnr": new["psnr"], "ssim_before_rule": old["ssim"], "ssim": new["ssim"],
           "foreground_px_before": int(sum(mk.sum() for mk in old_masks)),
           "foreground_px": int(sum((scene.masks[i] >= 1).sum() for i in idx))}
    if write:
        m["mean_before_mask_rule"] = dict(m["mean"])
        m["mean"].update(psnr=new["psnr"], ssim=new["ssim"])
        with open(mpath, "w") as fh:
            json.dump(m, fh, indent=1)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs")
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--write", action="store_true")
    a = ap.parse_args(argv)
    rows = []
    for dirpath, _, files in sorted(os.walk(a.runs)):
        if "metrics.json" in files and os.path.isdir(os.path.join(dirpath, "renders")):
            r = rescore(dirpath, a.data_root, a.write)
            if r is not None:
                rows.append(r)
                print(f"{dirpath}: PSNR {r['psnr_before_rule']:.3f} (mask > 0.5, area) -> {r['psnr']:.3f} "
                      f"(mask == 1, Pillow bicubic); SSIM {r['ssim_before_rule']:.4f} -> {r['ssim']:.4f}; "
                      f"foreground {r['foreground_px_before']} -> {r['foreground_px']} px")
    if not rows:
        print(f"{a.runs}: no DTU run with renders/", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
