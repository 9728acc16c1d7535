"""One line per `reings eval` run under RUNS (RUNS/TAG/<dataset>/reings/<V>views/<scene>/metrics.json), for a device
call's records (bench/gpu_call_env.sh):

  TAG scene views seed PSNR SSIM stages <coarse fine final s> training <s> total <s> gaussians <coarse fine final>
  options <fit_scale view_warp_scale fit_scale_share near_prune off_frame_margin> drops <near and off-frame per fit>

python bench/gpu_runs_table.py RUNS"""
import glob
import json
import os
import sys

FITS = ("coarse", "fine", "final")


def line(path: str, runs: str) -> str:
    m = json.load(open(path))
    s, c = m["seconds"], m["config"]
    tag = os.path.relpath(path, runs).split(os.sep)[0]
    drops = []
    for st in m["stages"]:
        if st["stage"] in FITS:
            d = st.get("history", {}).get("densify", [])
            drops.append(f"{sum(x.get('near', 0) for _, x in d)}/{sum(x.get('off_frame', 0) for _, x in d)}")
    opts = [c.get(k) for k in ("fit_scale", "view_warp_scale", "fit_scale_share", "near_prune", "off_frame_margin")]
    return " ".join(map(str, [
        tag, m["scene"], m["views"], m["seed"], repr(m["mean"]["psnr"]), round(m["mean"]["ssim"], 4),
        "stages", *(round(s[k], 1) for k in FITS), "training", round(sum(s[k] for k in FITS), 1),
        "total", round(s["total"], 1), "gaussians", *(m["gaussians"].get(k) for k in ("coarse", "fine", "final_prune" if "final_prune" in m["gaussians"] else "final")),
        "options", *(str(o).replace(" ", "") for o in opts), "drops", *drops]))


def main(runs: str) -> None:
    for path in sorted(glob.glob(os.path.join(runs, "*", "*", "reings", "*views", "*", "metrics.json"))):
        print(line(path, runs))


if __name__ == "__main__":
    main(sys.argv[1])
