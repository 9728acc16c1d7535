"""The `reings` command line: devices, bench, run, eval, worker, process, render, view, export.

Errors a user can cause (missing files, bad arguments, no OpenCL platform, an --out that already
holds a finished run) print one line `reings: error: ...` and exit with status 2; they are
checked before anything is written, and nothing already written is removed.
"""
from __future__ import annotations

import argparse
import json
import sys


class CLIError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


def _cmd_devices(args) -> int:
    from .backends.opencl.device import DeviceNotFound, list_devices

    try:
        devs = list_devices()
    except DeviceNotFound as e:
        raise CLIError(str(e)) from e
    except ImportError as e:
        raise CLIError(f"pyopencl is not installed ({e})") from e
    if args.json:
        print(json.dumps(devs, indent=1))
        return 0
    print("reference     float64 numpy reference (always available; slow, for tests and tiny scenes)")
    for d in devs:
        caps = [c for c, on in (("cpu", d["cpu"]), ("nv-ptx", d["nv_ptx"]), ("fp32-atomics", d["fp32_atomic_add"]), ("fp64", d["fp64"])) if on]
        alias = f" (= {d['alias']})" if d["alias"] else ""
        print(f"{d['spec']}{alias}: {d['device']} | {d['platform']} | {d['platform_version']} | driver {d['driver']} | "
              f"{d['opencl_c']} | {d['compute_units']} CUs, {d['global_mem_mb']} MiB, local {d['local_mem_kb']} KiB, "
              f"max work-group {d['max_work_group']} | {', '.join(caps)}")
    return 0


def _cmd_bench(args) -> int:
    from . import bench

    return bench.main(args.rest) or 0


def _cmd_run(args) -> int:
    from . import pipeline

    cfg = config_from_args(args)
    if not cfg.output.out:
        args.parser.error("the following arguments are required: --out (or output.out in --config)")
    return pipeline.main_run(cfg, overwrite=args.overwrite, quiet=args.quiet) or 0


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CLIError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 504x378") from None
    from .video import MAX_SIZE

    if w < 1 or h < 1 or w > MAX_SIZE or h > MAX_SIZE:
        raise CLIError(f"--size {text!r}: width and height must lie in 1..{MAX_SIZE}")
    return w, h


def _parse_background(text: str) -> tuple[float, float, float]:
    try:
        bg = tuple(float(v) for v in text.split(","))
    except ValueError:
        bg = ()
    if len(bg) != 3 or not all(0.0 <= v <= 1.0 for v in bg):
        raise CLIError(f"--background {text!r}: expected R,G,B in [0, 1], e.g. 1,1,1")
    return bg  # type: ignore[return-value]


def _cmd_render(args) -> int:
    import os

    from .paths import MAX_FRAMES
    from .video import FOURCC, check_codec, render_path

    if not 1 <= args.frames <= MAX_FRAMES:
        raise CLIError(f"--frames must be >= 1 and <= {MAX_FRAMES} (every frame is held in memory), got {args.frames}")
    if not args.fps > 0:
        raise CLIError(f"--fps must be positive, got {args.fps}")
    size = _parse_size(args.size) if args.size else None
    bg = _parse_background(args.background)
    path = "cameras" if args.cameras else args.path
    if not args.out and not args.frames_dir:
        raise CLIError("nothing to write: pass --out VIDEO and/or --frames-dir DIR")
    for p in (args.out, args.depth_out):
        if p and os.path.splitext(p)[1].lower() not in FOURCC:
            raise CLIError(f"{p}: unknown video extension (use {', '.join(FOURCC)})")
        if p and os.path.exists(p) and not args.overwrite:
            raise CLIError(f"{p} exists; pass --overwrite to replace it")
        if p and not os.path.isdir(os.path.dirname(os.path.abspath(p))):  # before rendering, not after
            raise CLIError(f"{p}: folder {os.path.dirname(os.path.abspath(p))} does not exist")
    if args.out and args.depth_out and os.path.abspath(args.out) == os.path.abspath(args.depth_out):
        raise CLIError(f"--out and --depth-out name the same file {args.out}; give the depth video its own name")
    _check_frames_dir(args.frames_dir, args.overwrite)
    for p in (args.out, args.depth_out):  # no codec: say so before rendering, not after
        if p:
            check_codec(p)
    pf = render_path(args.run, path=path, frames=args.frames, size=size, cameras=args.cameras,
                     device=args.device, background=bg, depth=bool(args.depth_out))
    h, w = pf.frames[0].shape[:2]
    if args.out:
        pf.write(args.out, fps=args.fps)
    if args.depth_out:
        pf.write_depth(args.depth_out, fps=args.fps)
    if args.frames_dir:
        pf.write_frames(args.frames_dir)
    wrote = ", ".join(p for p in (args.out, args.depth_out, args.frames_dir) if p)
    print(f"rendered {len(pf.frames)} frames {w}x{h} ({path}) of {pf.meta['gaussians']} Gaussians on {pf.device} "
          f"in {pf.seconds:.2f} s ({pf.fps:.1f} frames/s, encoding excluded) -> {wrote}")
    return 0


def _check_frames_dir(folder, overwrite: bool) -> None:
    """--frames-dir: a folder (or nothing yet) without frames of an earlier render, unless --overwrite."""
    import os

    if not folder:
        return
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise CLIError(f"--frames-dir {folder}: exists and is not a folder")
    if not overwrite and os.path.isdir(folder) and any(n.startswith("frame_") and n.endswith(".png")
                                                       for n in os.listdir(folder)):
        raise CLIError(f"--frames-dir {folder}: holds frames of an earlier render; pass --overwrite to replace them")


def _cmd_process(args) -> int:
    from .data.process import main_process

    return main_process(args)


def _cmd_view(args) -> int:
    import socket

    from .viewer import main_view

    if not 1 <= args.port <= 65535:
        raise CLIError(f"--port must lie in 1..65535, got {args.port}")
    try:
        socket.getaddrinfo(args.host, args.port)
    except (OSError, UnicodeError) as e:  # socket.gaierror is an OSError
        raise CLIError(f"--host {args.host!r}: not an address this machine can listen on ({e})") from None

    try:
        return main_view(args)
    except ImportError as e:
        raise CLIError(str(e)) from e


def _cmd_worker(args) -> int:
    from .cluster import main_worker

    return main_worker(args)


def _cmd_export(args) -> int:
    from .export import export_run

    paths = export_run(args.run, args.out, format=args.format, sh_degree=args.sh_degree, overwrite=args.overwrite)
    print("\n".join(paths))
    return 0


def _cmd_eval(args) -> int:
    from . import evaluate

    return evaluate.main_eval(args, config_from_args(args)) or 0


# {{{ options generated from reings.config.RunConfig

_DEST = "config:"  # argparse dest prefix of the generated options: "config:reings.cvps_fraction"


def option_name(path: str, f) -> str:
    """The command-line spelling of a RunConfig field: its `cli` metadata, else --leaf-name."""
    return f.metadata.get("cli") or "--" + path.rsplit(".", 1)[-1].replace("_", "-")


def _optional_bool(text: str):
    """The value of an optional switch given with one: none, true or false."""
    t = text.strip().lower()
    if t in ("none", "true", "false"):
        return {"none": None, "true": True, "false": False}[t]
    raise argparse.ArgumentTypeError(f"expected none, true or false, got {text!r}")


def _option_type(f, tp):
    """argparse `type=` of a field: the text parsed as the annotation says ("none" for an optional
    field), then the field's choices and check; an error says what was expected."""
    from .config import check_value, optional_of

    inner = optional_of(tp)
    kind = inner if inner is not None else tp
    parse = f.metadata.get("parse")

    def convert(text: str):
        if inner is not None and text.strip().lower() == "none":
            return None
        try:
            if parse is not None:
                v = parse(text)
            elif kind in (int, float):
                try:
                    v = kind(text)
                except ValueError:
                    raise ValueError(f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") from None
            else:
                v = text
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        why = check_value(f, v)
        if why:
            raise argparse.ArgumentTypeError(why)
        return v

    convert.__name__ = getattr(kind, "__name__", "value")
    return convert


def _default_text(v) -> str:
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "on" if v else "off"
    if isinstance(v, tuple):
        return ",".join(map(str, v)) if v else "none"
    return str(v)


def add_config_options(parser: argparse.ArgumentParser, exclude=()) -> None:
    """One option per RunConfig field (dotted paths in `exclude` left out), in an argument group
    per section; help = the field's documentation; default = argparse.SUPPRESS, so the namespace
    holds only what was given (`config_from_args` lays it over --config or the defaults)."""
    from dataclasses import MISSING, fields

    from .config import RunConfig, leaf_fields, optional_of

    groups = {"": parser.add_argument_group("run options (reings.config.RunConfig)")}
    for f in fields(RunConfig):
        if f.default_factory is not MISSING:
            cls = f.default_factory
            groups[f.name] = parser.add_argument_group(
                f"{f.name} options (RunConfig.{f.name}, {cls.__name__}: {cls.__doc__.strip().rstrip('.')})")
    for path, f, tp in leaf_fields(RunConfig):
        if path in exclude:
            continue
        group = groups[path.rpartition(".")[0]]
        default = f.default if f.default is not MISSING else f.default_factory()
        help_ = f"{f.metadata.get('help', '')} (default: {_default_text(default)})".replace("%", "%%")
        kw = {"dest": _DEST + path, "default": argparse.SUPPRESS, "help": help_}
        if tp is bool:
            group.add_argument(option_name(path, f), action=argparse.BooleanOptionalAction, **kw)
            continue
        if optional_of(tp) is bool:  # --x (true), --no-x (false), --x none|true|false
            name = option_name(path, f)
            kw["help"] = f"{help_} [--{name[2:]} alone: true; --no-{name[2:]}: false]"
            group.add_argument(name, nargs="?", const=True, type=_optional_bool, metavar="{none,true,false}", **kw)
            group.add_argument("--no-" + name[2:], action="store_const", const=False, dest=kw["dest"],
                               default=argparse.SUPPRESS, help=argparse.SUPPRESS)
            continue
        choices = f.metadata.get("choices")
        metavar = (f.metadata.get("metavar") or ("{" + ",".join(map(str, choices)) + "}" if choices else None)
                   or path.rsplit(".", 1)[-1].upper())
        group.add_argument(option_name(path, f), type=_option_type(f, tp), metavar=metavar, **kw)


def options_markdown() -> str:
    """The options table of docs/pipeline.md, from RunConfig (tests/test_config.py keeps the doc
    equal to it): `python -c "from reings.cli import options_markdown as m; print(m())"`."""
    from dataclasses import MISSING

    from .config import leaf_fields, optional_of

    rows = ["| option | RunConfig field | default | meaning |", "|---|---|---|---|"]
    for path, f, tp in leaf_fields():
        name = option_name(path, f)
        if tp is bool or optional_of(tp) is bool:
            name += f"`, `--no-{name[2:]}"
        default = f.default if f.default is not MISSING else f.default_factory()
        text = " ".join(f.metadata.get("help", "").split()).replace("|", "\\|")
        rows.append(f"| `{name}` | `{path}` | {_default_text(default)} | {text} |")
    return "\n".join(rows) + "\n"


def config_from_args(args):
    """The RunConfig of parsed arguments: --config FILE (else the defaults) with every generated
    option that was given laid over it."""
    from .config import RunConfig, load_run_config, with_values

    base = load_run_config(args.config) if getattr(args, "config", None) else RunConfig()
    given = {k[len(_DEST):]: v for k, v in vars(args).items() if k.startswith(_DEST)}
    return with_values(base, given)
# }}}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="reings", description="Few-shot 3D Gaussian splatting (ReInGS) on OpenCL.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("devices", help="list OpenCL devices with versions and capabilities")
    d.add_argument("--json", action="store_true", help="machine-readable output")
    d.set_defaults(func=_cmd_devices)

    b = sub.add_parser("bench", help="kernel microbenchmarks (run `reings bench --help`)", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_cmd_bench)

    config_help = "a RunConfig as TOML (a run's config.toml, say); the options given here override it"
    r = sub.add_parser("run", help="fit one scene and evaluate its test views (docs/pipeline.md)",
                       description="Fit one scene and evaluate its test views. Every option is a field of "
                                   "reings.config.RunConfig; the run writes the resolved one as config.toml.")
    r.add_argument("--config", metavar="TOML", help=config_help)
    r.add_argument("--overwrite", action="store_true", help="redo a finished run in --out (starts over)")
    r.add_argument("--quiet", action="store_true", help="no progress bars or stage lines")
    add_config_options(r)
    r.set_defaults(func=_cmd_run, parser=r)

    e = sub.add_parser("eval", help="run every scene x view count x method (x seed) of a dataset and tabulate "
                                    "(docs/pipeline.md)",
                       description="Run every scene x view count x method x seed of a dataset, one `reings run` "
                                   "folder each, and tabulate. The run options apply to every run.")
    e.add_argument("--config", metavar="TOML", help=config_help)
    e.add_argument("--root", default=None, help="folder of scene folders (e.g. nerf_llff_data/)")
    e.add_argument("--scenes", default=None, help="comma list of scene folder names (default: every scene under --root)")
    e.add_argument("--views", default=None, help="comma list of training-view counts, e.g. 2,3,4 (default: the "
                                                 "config's views, 3)")
    e.add_argument("--methods", "--method", dest="methods", default=None,
                   help="comma list: reings, dngaussian, 3dgs, reings-no-ehps, reings-no-ivps, reings-no-cvps, ... "
                        "(default: the config's method, reings)")
    e.add_argument("--seeds", default=None, help="comma list of seeds, one run folder per seed; the tables show "
                                                 "the mean over seeds and its min-max (default: --seed, 0)")
    e.add_argument("--out", required=True, help="results folder: one run folder per dataset/method/views/scene(/seed)")
    e.add_argument("--table-only", action="store_true", help="only rebuild results.json/results.md from the runs in --out")
    e.add_argument("--prepare-only", action="store_true",
                   help="only fill the depth-prior and SfM caches of every scene x view count (no training)")
    e.add_argument("--keep-going", action="store_true", help="go on with the other runs when one fails")
    e.add_argument("--cluster", metavar="local[:N]|tcp://HOST:PORT",
                   help="run the grid as Dask tasks: a local cluster (one worker per GPU, or N workers: GPUs "
                        "first, then PoCL on the spare cores) or an existing scheduler (extra: cluster; "
                        "docs/cluster.md)")
    e.add_argument("--gpu-only", action="store_true", help="with --cluster: tasks ask for the resource GPU=1")
    e.add_argument("--runs-per-gpu", type=int, default=1, metavar="K",
                   help="with --cluster local: K workers per GPU, so K runs share each GPU (default 1; "
                        "docs/cluster.md has the measured runs per hour)")
    e.add_argument("--quiet", action="store_true", help="no progress bars or stage lines")
    add_config_options(e, exclude=EVAL_SETS)
    e.set_defaults(func=_cmd_eval, parser=e)

    q = sub.add_parser("process", help="register a folder of photos with COLMAP into a scene `reings run` reads",
                       description="Structure from motion of unposed photos (pycolmap, CPU): features, matching, "
                                   "mapping, undistortion to PINHOLE cameras. Writes SCENE_DIR/images, "
                                   "SCENE_DIR/sparse/0 and SCENE_DIR/process.json.")
    q.add_argument("photos", metavar="PHOTOS_DIR", help="folder of photos (png, jpg, ...) of one scene")
    q.add_argument("--out", required=True, metavar="SCENE_DIR", help="the scene folder to write")
    q.add_argument("--overwrite", action="store_true", help="replace a non-empty SCENE_DIR (once the new one is done)")
    q.add_argument("--partial", action="store_true", help="make the scene from the photos that register when "
                                                          "some do not (default: an error naming them)")
    q.add_argument("--per-image-camera", action="store_true", help="one camera per photo (photos from different "
                                                                   "cameras or zoom settings); default: one shared")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    q.set_defaults(func=_cmd_process)

    v = sub.add_parser("render", help="render a fly-through video of a finished run (docs/product.md)",
                       description="Render a camera path of a finished run (its gaussians.ply and cameras.json) "
                                   "into a video, PNG frames and/or a colour-mapped depth video.")
    v.add_argument("run", metavar="RUN_DIR", help="a finished `reings run` folder")
    v.add_argument("--path", default="spiral", choices=("spiral", "ellipse", "interpolate"),
                   help="spiral: the LLFF forward-facing spiral; ellipse: a loop around an object; interpolate: "
                        "through the training views (default: spiral)")
    v.add_argument("--cameras", metavar="FILE", help="render the cameras of this cameras.json as given (no path)")
    v.add_argument("--frames", type=int, default=120, help="frames of the path (default 120)")
    v.add_argument("--fps", type=float, default=30.0, help="frames per second of the video (default 30)")
    v.add_argument("--size", metavar="WxH", help="frame size (default: the training images')")
    v.add_argument("--background", default="0,0,0", metavar="R,G,B", help="background colour in [0, 1] (default black)")
    v.add_argument("--device", default="pocl", help="pocl | cuda | cuda:N | opencl:P:D | reference")
    v.add_argument("--out", metavar="VIDEO", help="video file (.mp4, .avi, ...)")
    v.add_argument("--depth-out", metavar="VIDEO", help="also a colour-mapped depth video")
    v.add_argument("--frames-dir", metavar="DIR", help="also one PNG per frame in DIR")
    v.add_argument("--overwrite", action="store_true", help="replace existing video files and --frames-dir frames")
    v.set_defaults(func=_cmd_render)

    w = sub.add_parser("view", help="an interactive viewer of a run or a .ply in the browser (extra: view)",
                       description="Serve the Gaussians of a finished run (or any 3DGS .ply) to the browser "
                                   "with viser, the training cameras drawn as frustums.")
    w.add_argument("model", metavar="RUN_DIR|PLY", help="a finished `reings run` folder or a 3DGS .ply file")
    w.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; 0.0.0.0 for all)")
    w.add_argument("--port", type=int, default=8080, help="port (default 8080)")
    w.set_defaults(func=_cmd_view)

    k = sub.add_parser("worker", help="a Dask worker for `reings eval --cluster tcp://...`, bound to one device",
                       description="Start a Dask worker (under a nanny that restarts it) bound to one device: it "
                                   "runs one run at a time (resource RUN=1, and GPU=1 on a GPU). Extra: cluster.")
    k.add_argument("--scheduler", required=True, metavar="tcp://HOST:PORT", help="the Dask scheduler's address")
    k.add_argument("--device", default="pocl", help="pocl | cuda | cuda:N | opencl:P:D")
    k.add_argument("--pocl-threads", type=int, default=0, help="PoCL: threads of this worker (default: all cores)")
    k.add_argument("--runs", type=int, default=1, metavar="K",
                   help="K workers on this device, K runs sharing it (default 1)")
    k.add_argument("--name", default="", help="worker name shown by the dashboard")
    k.set_defaults(func=_cmd_worker)

    x = sub.add_parser("export", help="export a finished run's model (PLY with SH degree 3, or the 3DGS/Inria "
                                      "folder layout)")
    x.add_argument("run", metavar="RUN_DIR", help="a finished `reings run` folder")
    x.add_argument("--format", default="ply", choices=("ply", "inria"),
                   help="ply: OUT/point_cloud.ply; inria: point_cloud/iteration_N/point_cloud.ply, cameras.json, "
                        "cfg_args (default ply)")
    x.add_argument("--sh-degree", type=int, default=3, choices=(0, 1, 2, 3),
                   help="SH degree of the exported PLY, zero-padded (default 3)")
    x.add_argument("--out", required=True, metavar="DIR", help="output folder")
    x.add_argument("--overwrite", action="store_true", help="replace existing files in --out")
    x.set_defaults(func=_cmd_export)

    return p


# RunConfig fields `reings eval` sets per run (its --methods, --views, --seeds, --root/--scenes, --out)
EVAL_SETS = ("method", "views", "data", "output.out")


def main(argv=None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bench"]:  # argparse's REMAINDER does not take leading options: pass them through
        args = argparse.Namespace(func=_cmd_bench, rest=argv[1:])
    else:
        args = parser.parse_args(argv)
    from .log import configure_cli

    configure_cli(bool(getattr(args, "quiet", False)))
    try:
        return int(args.func(args) or 0)
    except CLIError as e:
        print(f"reings: error: {e}", file=sys.stderr)
        return 2
    except (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError, PermissionError,
            ValueError) as e:
        print(f"reings: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a write that failed (full disk, a PNG OpenCV refused): one line naming the path
        print(f"reings: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("reings: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # device errors carry their own class names
        name = type(e).__name__
        if name in ("DeviceNotFound", "KernelBuildError", "SceneError", "DepthPriorError", "LPIPSModelNotFound",
                    "CamerasFileError", "PlyError", "ClusterError"):
            print(f"reings: error: {e}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
