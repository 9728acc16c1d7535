"""The `reings` command line: devices, bench, run, eval.

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


def _cmd_eval(args) -> int:
    from . import evaluate

    return evaluate.main_eval(args, config_from_args(args)) or 0


# {{{ options generated from reings.config.RunConfig

_DEST = "config:"  # argparse dest prefix of the generated options: "config:reings.cvps_fraction"


def option_name(path: str, f) -> str:
    """The command-line spelling of a RunConfig field: its `cli` metadata, else --leaf-name."""
    return f.metadata.get("cli") or "--" + path.rsplit(".", 1)[-1].replace("_", "-")


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
        return ",".join(map(str, v))
    return str(v)


def add_config_options(parser: argparse.ArgumentParser, exclude=()) -> None:
    """One option per RunConfig field (dotted paths in `exclude` left out), in an argument group
    per section; help = the field's documentation; default = argparse.SUPPRESS, so the namespace
    holds only what was given (`config_from_args` lays it over --config or the defaults)."""
    from dataclasses import MISSING, fields

    from .config import RunConfig, leaf_fields

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
        choices = f.metadata.get("choices")
        metavar = (f.metadata.get("metavar") or ("{" + ",".join(map(str, choices)) + "}" if choices else None)
                   or path.rsplit(".", 1)[-1].upper())
        group.add_argument(option_name(path, f), type=_option_type(f, tp), metavar=metavar, **kw)


def options_markdown() -> str:
    """The options table of docs/pipeline.md, from RunConfig (tests/test_config.py keeps the doc
    equal to it): `python -c "from reings.cli import options_markdown as m; print(m())"`."""
    from dataclasses import MISSING

    from .config import leaf_fields

    rows = ["| option | RunConfig field | default | meaning |", "|---|---|---|---|"]
    for path, f, tp in leaf_fields():
        name = option_name(path, f)
        if tp is bool:
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
    e.add_argument("--quiet", action="store_true", help="no progress bars or stage lines")
    add_config_options(e, exclude=EVAL_SETS)
    e.set_defaults(func=_cmd_eval, parser=e)

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
        if name in ("DeviceNotFound", "KernelBuildError", "SceneError", "DepthPriorError", "LPIPSModelNotFound"):
            print(f"reings: error: {e}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
