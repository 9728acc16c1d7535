"""What a run writes into its output folder, and how the folder is claimed.

    check_out(out, settings, overwrite)     refuse a finished run (unless overwrite), an
                                            interrupted run of other settings or unknown settings
                                            (fail closed), a symlink at checkpoints/, renders/,
                                            depths/ or .previous-run; writes nothing
    prepare_out(out, settings, overwrite)   the same, then claim: with overwrite the previous run
                                            moves to out/.previous-run (finish_out deletes it after
                                            the new run's metrics.json, restore_out puts it back
                                            when the new run fails); checkpoints/run.json
    write_config(out, config)               config.toml: the resolved RunConfig (reings.config.to_toml)
    write_test_renders(out, names, rgbs, depths)   renders/<name>.png (8-bit RGB),
                                            depths/<name>.png (16-bit, min-max normalised)
    write_run_outputs(out, gaussians, metrics, series, bounds, title, members)
                                            gaussians.ply (an ensemble's other members:
                                            gaussians_member<k>.ply), psnr_vs_time.svg, then metrics.json
                                            (last: its presence marks a finished run)
    write_json_atomic / write_text_atomic / jsonable / psnr_time_svg   the pieces

Every file is written whole or not at all (`reings.io.files.atomic_write`), except the PNGs and
the PLY, which a finished run's metrics.json vouches for. docs/pipeline.md lists the files.
"""
from __future__ import annotations

import dataclasses
import json
import os
import re

import numpy as np

RUN_OUTPUTS = ("metrics.json", "config.toml", "cameras.json", "psnr_vs_time.svg", "gaussians.ply")


def jsonable(x):
    """`x` with numpy scalars and arrays, tuples and dataclasses turned into JSON types (non-finite
    floats become None)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return jsonable(dataclasses.asdict(x))
    return x


def write_json_atomic(path: str, obj) -> None:
    """json.dump to `path` through a temp file in the same folder + rename (never half-written)."""
    from .io.files import atomic_write

    with atomic_write(path) as f:
        json.dump(jsonable(obj), f, indent=1)


def write_text_atomic(path: str, text: str) -> None:
    from .io.files import atomic_write

    with atomic_write(path) as f:
        f.write(text)


PREVIOUS = ".previous-run"  # where --overwrite keeps the replaced run until the new one finishes
RUN_FOLDERS = ("renders", "depths")
MEMBER_PLY = re.compile(r"gaussians_member[1-9][0-9]*\.ply")  # an ensemble's members 1..K-1 (`member_ply`)


def check_out(out: str, settings: dict, overwrite: bool) -> None:
    """Everything `prepare_out` would refuse, without writing anything (called before any work):
    a non-folder `out`, a finished run (unless overwrite), an interrupted run of other settings
    or with an unreadable checkpoints/run.json (unless overwrite: fail closed)."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    for name in ("checkpoints", PREVIOUS) + RUN_FOLDERS:  # a run writes into --out, never through a planted link
        if os.path.islink(os.path.join(out, name)):
            raise ValueError(f"{os.path.join(out, name)} is a symlink; reings does not write through links in --out "
                             "(remove it, or use another --out)")
    if overwrite:
        return
    if os.path.exists(os.path.join(out, "metrics.json")):
        raise FileExistsError(f"{out} already holds a finished run (metrics.json); pass --overwrite to redo it")
    run_json = os.path.join(out, "checkpoints", "run.json")
    if not os.path.exists(run_json):
        return
    try:
        with open(run_json) as f:
            old = json.load(f)
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as e:
        raise ValueError(f"{run_json}: unreadable ({e}); the interrupted run's settings are unknown, so it is not "
                         "resumed: pass --overwrite to start over, or another --out") from None
    want = jsonable(settings)
    if old != want:
        diff = sorted(k for k in set(old) | set(want) if old.get(k) != want.get(k))
        said = ", ".join(f"{k}: {old.get(k)!r} there, {want.get(k)!r} now" for k in diff)  # absent: None
        raise ValueError(f"{out} holds an interrupted run with other settings ({said}); "
                         "pass --overwrite to start over, or another --out")


def _old_run_entries(out: str) -> list[str]:
    """The entries of `out` that belong to a run: its files, render folders and checkpoints."""
    names = [n for n in RUN_OUTPUTS + RUN_FOLDERS if os.path.lexists(os.path.join(out, n))]
    names += sorted(n for n in os.listdir(out) if MEMBER_PLY.fullmatch(n)) if os.path.isdir(out) else []
    ck = os.path.join(out, "checkpoints")
    if os.path.isdir(ck):
        names += [os.path.join("checkpoints", n) for n in sorted(os.listdir(ck))
                  if n.endswith(".npz") or n == "run.json"]
    return names


def prepare_out(out: str, settings: dict, overwrite: bool) -> None:
    """Claim `out` for a run with `settings` (checkpoints/run.json) after `check_out`. With
    overwrite the previous run is not deleted but moved into `out/.previous-run/`; `finish_out`
    deletes it once the new run has written metrics.json, `restore_out` puts it back when the new
    run fails. (A `.previous-run` left by an overwrite that was killed already holds the last
    finished run: it is kept, and the killed run's partial outputs are removed.)"""
    import shutil

    check_out(out, settings, overwrite)
    ckdir = os.path.join(out, "checkpoints")
    _remove_stale_temps(out)
    if overwrite:
        prev = os.path.join(out, PREVIOUS)
        keep_old = not os.path.isdir(prev)
        for name in _old_run_entries(out):
            src = os.path.join(out, name)
            if keep_old:
                dst = os.path.join(prev, name)
                os.makedirs(os.path.dirname(dst), exist_ok=True)
                os.replace(src, dst)
            elif os.path.isdir(src) and not os.path.islink(src):
                shutil.rmtree(src)
            else:
                os.unlink(src)
    os.makedirs(ckdir, exist_ok=True)
    write_json_atomic(os.path.join(ckdir, "run.json"), settings)


def _remove_stale_temps(out: str) -> None:
    """Delete the `.tmp-*` files (reings.io.files.atomic_write, PNG writes) that a killed run left
    in `out`, its checkpoints, renders and depths: no live writer owns them once the folder is
    claimed again (`reings eval` holds a lock per run folder; two `reings run` into one folder at
    the same time are not supported)."""
    for d in (out, *(os.path.join(out, n) for n in ("checkpoints",) + RUN_FOLDERS)):
        if not os.path.isdir(d):
            continue
        for n in os.listdir(d):
            p = os.path.join(d, n)
            if n.startswith(".tmp-") and (os.path.islink(p) or os.path.isfile(p)):
                os.unlink(p)


def finish_out(out: str) -> None:
    """After a finished run: delete the run that --overwrite replaced (`prepare_out`)."""
    import shutil

    prev = os.path.join(out, PREVIOUS)
    if os.path.isdir(prev) and not os.path.islink(prev):
        shutil.rmtree(prev)


def restore_out(out: str) -> bool:
    """After a failed run: put the run that --overwrite replaced back (its files over the failed
    run's). Returns True if there was one."""
    import shutil

    prev = os.path.join(out, PREVIOUS)
    if os.path.islink(prev) or not os.path.isdir(prev):  # a planted link is not a run of ours: never moved in
        return False
    for name in _old_run_entries(out):  # the failed run's partial outputs
        p = os.path.join(out, name)
        if os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p)
        else:
            os.unlink(p)
    for name in _old_run_entries(prev):
        dst = os.path.join(out, name)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        os.replace(os.path.join(prev, name), dst)
    shutil.rmtree(prev)
    return True


def write_config(out: str, config) -> str:
    """config.toml in `out`: the run's resolved configuration (`reings run --config` reads it)."""
    from .config import to_toml

    path = os.path.join(out, "config.toml")
    write_text_atomic(path, to_toml(config))
    return path


def write_test_renders(out: str, names, rgbs, depths) -> None:
    """renders/<stem>.png (8-bit RGB, rounded) and depths/<stem>.png (16-bit, each map min-max
    normalised) of the test views."""
    import cv2

    os.makedirs(os.path.join(out, "renders"), exist_ok=True)
    os.makedirs(os.path.join(out, "depths"), exist_ok=True)
    for name, p, d in zip(names, rgbs, depths):
        stem = os.path.splitext(os.path.basename(name))[0]
        write_png_atomic(os.path.join(out, "renders", stem + ".png"),
                   cv2.cvtColor((p * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))
        dn = (d - d.min()) / max(float(d.max() - d.min()), 1e-9)
        write_png_atomic(os.path.join(out, "depths", stem + ".png"), (dn * 65535).astype(np.uint16))


def write_png_atomic(path: str, a: np.ndarray) -> None:
    """`a` encoded as a PNG by OpenCV in memory, then written whole through `atomic_write` (a unique
    temporary file in the same folder, renamed over `path`). cv2.imwrite is not used: it reports a
    write the OS refuses (a full disk, a file-size limit) as success and leaves a truncated file.
    OSError naming the file when OpenCV cannot encode the array or the OS refuses the write."""
    import cv2

    from .io.files import atomic_write

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a))
    if not ok:
        raise OSError(f"{path}: could not write the PNG (cv2.imencode failed)")
    with atomic_write(path, binary=True) as f:
        f.write(buf.tobytes())


def member_ply(k: int) -> str:
    """The file name of ensemble member k's model (member 0: gaussians.ply)."""
    return "gaussians.ply" if k == 0 else f"gaussians_member{k}.ply"


def member_plys(out: str) -> list[str]:
    """The model files of the run in `out`, member 0 first: gaussians.ply and gaussians_member1.ply,
    gaussians_member2.ply, ... up to the first missing one."""
    names = []
    while os.path.isfile(os.path.join(out, member_ply(len(names)))):
        names.append(member_ply(len(names)))
    return names


def write_run_outputs(out: str, gaussians, metrics: dict, series: list, bounds: list, title: str,
                      members=()) -> None:
    """gaussians.ply (and gaussians_member<k>.ply of `members`, an ensemble's members 1..K-1),
    psnr_vs_time.svg (when there are probes), then metrics.json, last."""
    from .io.ply import write_ply

    write_ply(os.path.join(out, "gaussians.ply"), gaussians)
    for k, g in enumerate(members, start=1):
        write_ply(os.path.join(out, member_ply(k)), g)
    if series:
        write_text_atomic(os.path.join(out, "psnr_vs_time.svg"), psnr_time_svg(series, bounds, title))
    write_json_atomic(os.path.join(out, "metrics.json"), metrics)  # last: marks the run finished


# {{{ the PSNR-vs-seconds SVG

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
# }}}
