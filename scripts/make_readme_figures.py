#!/usr/bin/env python3
"""The README's pictures, made from a real finished run (nothing drawn by hand).

    python scripts/make_readme_figures.py RUN_DIR [--out docs/img] [--device pocl]

Writes, small enough to commit:
    <out>/render_vs_gt.jpg   the run's render of its first test view next to the ground truth,
                             with the view's PSNR (from metrics.json)
    <out>/psnr_vs_time.svg   the run's own PSNR-against-seconds plot
    <out>/flythrough.jpg     6 frames of the LLFF spiral (`reings render --path spiral`)
The ground truth is read from the run's `data` folder (its `test_indices`).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

import numpy as np


def _label(im, text):
    import cv2

    out = im.copy()
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
    out[:h + 14, :w + 14] = (out[:h + 14, :w + 14] * 0.25).astype(out.dtype)  # a dark banner behind the text
    cv2.putText(out, text, (7, h + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def main(argv=None) -> int:
    import cv2

    import reings
    from reings.video import render_path

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("--out", default="docs/img")
    ap.add_argument("--device", default="pocl")
    a = ap.parse_args(argv)
    m = json.load(open(os.path.join(a.run, "metrics.json")))
    os.makedirs(a.out, exist_ok=True)
    scene = reings.load_scene(m["data"], factor=m["run_config"]["factor"])
    i = m["test_indices"][0]
    name = os.path.splitext(os.path.basename(scene.names[i]))[0]
    render = cv2.imread(os.path.join(a.run, "renders", name + ".png"))
    gt = np.clip(np.rint(scene.images[i] * 255), 0, 255).astype(np.uint8)[..., ::-1]
    psnr = m["per_image"]["psnr"][0] if isinstance(m.get("per_image"), dict) else m["mean"]["psnr"]
    pair = np.concatenate([_label(render, f"reings, {m['views']} views: {psnr:.2f} dB"),
                           np.full((render.shape[0], 6, 3), 255, np.uint8), _label(gt, "ground truth (held out)")], 1)
    cv2.imwrite(os.path.join(a.out, "render_vs_gt.jpg"), pair, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if os.path.isfile(os.path.join(a.run, "psnr_vs_time.svg")):
        shutil.copy(os.path.join(a.run, "psnr_vs_time.svg"), os.path.join(a.out, "psnr_vs_time.svg"))
    w, h = render.shape[1] // 2, render.shape[0] // 2
    pf = render_path(a.run, path="spiral", frames=24, size=(w, h), device=a.device)
    strip = np.concatenate([f[..., ::-1] for f in pf.frames[::4]], 1)
    cv2.imwrite(os.path.join(a.out, "flythrough.jpg"), strip, [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {a.out}/render_vs_gt.jpg, psnr_vs_time.svg, flythrough.jpg from {a.run}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
