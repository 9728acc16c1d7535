"""The `reings` command line: devices, bench, run.

Errors a user can cause (missing files, bad arguments, no OpenCL platform) print one line
`reings: error: ...` and exit with status 2; nothing already written is removed.
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

    return pipeline.main_run(args) or 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="reings", description="Few-shot 3D Gaussian splatting (ReInGS) on OpenCL.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("devices", help="list OpenCL devices with versions and capabilities")
    d.add_argument("--json", action="store_true", help="machine-readable output")
    d.set_defaults(func=_cmd_devices)

    b = sub.add_parser("bench", help="kernel microbenchmarks (run `reings bench --help`)", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_cmd_bench)

    r = sub.add_parser("run", help="fit one scene and evaluate its test views")
    r.add_argument("--method", default="reings", choices=["reings", "dngaussian", "3dgs"])
    r.add_argument("--data", default=None, help="scene folder; omitted: the built-in procedural scene")
    r.add_argument("--dataset", default=None, choices=["llff", "dtu", "colmap", "blender", "procedural"])
    r.add_argument("--factor", type=int, default=8, help="LLFF image downsampling factor")
    r.add_argument("--views", type=int, default=3, help="number of training views")
    r.add_argument("--device", default="pocl", help="pocl | cuda | opencl:P:D | reference")
    r.add_argument("--depth-prior", default="stereo", help="stereo | onnx:PATH | none")
    r.add_argument("--preset", default="quick", choices=["quick", "paper"])
    r.add_argument("--iterations", type=int, default=None, help="override the preset's iteration count per stage")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty --out")
    r.add_argument("--quiet", action="store_true")
    r.set_defaults(func=_cmd_run)

    return p


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
    except (FileNotFoundError, ValueError) as e:
        print(f"reings: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("reings: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # device errors carry their own class names
        name = type(e).__name__
        if name in ("DeviceNotFound", "KernelBuildError", "SceneError"):
            print(f"reings: error: {e}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
