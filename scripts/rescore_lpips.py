#!/usr/bin/env python3
"""Add LPIPS (and AVGE) to finished runs whose metrics.json lacks them.

    python scripts/rescore_lpips.py RUNS_DIR [--data-root DIR] [--model lpips_vgg.onnx]

Why: the 59 MB VGG LPIPS model cannot travel to the lent GPU machine with the data (64 MiB per
call), so GPU runs are scored there without LPIPS (`lpips_error` in metrics.json) and rescored
here from the saved 8-bit test renders (`renders/<name>.png`), which is what the 3DGS-family
metric scripts read too. PSNR/SSIM stay the float values computed at the end of the run; LPIPS
comes from the PNGs; AVGE is recomputed per image from the three and then averaged.

Test images come from the run's own `data` path and `test_indices`; `--data-root` replaces the
folder part of `data` that does not exist here (e.g. the GPU machine's staging path).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np


def _load_png(path: str) -> np.ndarray:
    import cv2

    im = cv2.imread(path, cv2.IMREAD_COLOR)
    if im is None:
        raise ValueError(f"{path}: unreadable PNG")
    return cv2.cvtColor(im, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0


def rescore(run_dir: str, data_root: str | None, model: str | None, force: bool = False) -> bool:
    from reings import load_scene, metrics

    mpath = os.path.join(run_dir, "metrics.json")
    with open(mpath) as fh:
        m = json.load(fh)
    if m.get("mean", {}).get("lpips") is not None and not force:
        return False
    cfg = m.get("config") or {}
    data = cfg.get("data") or m["data"]
    if data in (None, "procedural"):
        from reings import make_procedural_scene

        scene = make_procedural_scene()
    else:
        if not os.path.isdir(data) and data_root:
            data = os.path.join(data_root, os.path.basename(os.path.normpath(data)))
        scene = load_scene(data, cfg.get("dataset"), factor=cfg.get("factor", 8))
    test = scene.subset(m["test_indices"])
    preds = [_load_png(os.path.join(run_dir, "renders", os.path.splitext(os.path.basename(n))[0] + ".png"))
             for n in test.names]
    masks = test.masks
    lp = [metrics.lpips(p, r, model=model, mask=None if masks is None else masks[i])
          for i, (p, r) in enumerate(zip(preds, test.images))]
    per = m.setdefault("per_image", {}) or {}
    per["lpips"] = lp
    per["avge"] = [float(x) for x in metrics.avge(per["psnr"], per["ssim"], lp)]
    m["per_image"] = per
    m["mean"]["lpips"] = float(np.mean(lp))
    m["mean"]["avge"] = float(np.mean(per["avge"]))
    m["lpips_source"] = "8-bit test renders (renders/*.png), rescored by scripts/rescore_lpips.py"
    m.pop("lpips_error", None)
    tmp = mpath + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(m, fh, indent=1)
    os.replace(tmp, mpath)
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs")
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--model", default=None)
    ap.add_argument("--force", action="store_true", help="rescore runs that already have LPIPS")
    a = ap.parse_args(argv)
    n, failed = 0, []
    for dirpath, _, files in sorted(os.walk(a.runs)):
        if "metrics.json" in files:
            try:
                if rescore(dirpath, a.data_root, a.model, a.force):
                    n += 1
                    print(f"rescored {dirpath}")
            except Exception as e:  # e.g. a run whose renders did not come back: report, go on
                failed.append(dirpath)
                print(f"{dirpath}: not rescored: {type(e).__name__}: {e}", file=sys.stderr)
    print(f"{n} run(s) rescored, {len(failed)} not")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
