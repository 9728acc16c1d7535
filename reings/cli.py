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

    return pipeline.main_run(args) or 0


def _cmd_eval(args) -> int:
    from . import evaluate

    return evaluate.main_eval(args) or 0


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _fraction(text: str) -> float:
    v = _number(text)
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {v}")
    return v


def _prune_fraction(text: str) -> float:
    v = _number(text)
    if not 0.0 <= v < 1.0:  # also refuses nan
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1) (0 = off), got {text}")
    return v


def _nonneg_float(text: str) -> float:
    v = _number(text)
    if not (v >= 0.0 and v != float("inf")):  # also refuses nan
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return v


def _iterations(text: str):
    """N, or A,B,C (reings: coarse, fine, final): positive integers."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (1, 3):
        raise argparse.ArgumentTypeError(f"expected N or A,B,C (three stages), got {text!r}")
    vals = tuple(_positive_int(p) for p in parts)
    return vals[0] if len(vals) == 1 else vals


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {v}")
    return v


def _add_common_fit_args(r, methods_flag: str) -> None:
    """Options shared by `run` and `eval`."""
    r.add_argument("--device", default="pocl", help="pocl | cuda | cuda:N | opencl:P:D | reference")
    r.add_argument("--depth-prior", default="stereo", help="stereo | onnx:PATH | none | exact (procedural only)")
    r.add_argument("--preset", default="quick", choices=["quick", "paper"],
                   help="iteration counts: quick (3dgs/dngaussian 600, reings 200/200/600) or paper (6000 per stage)")
    r.add_argument("--iterations", type=_iterations, default=None,
                   help="override the preset's iteration count: N (every stage) or, for reings, A,B,C per stage")
    r.add_argument("--eval-every", type=_nonneg_int, default=None,
                   help="test-PSNR probe every N iterations for the PSNR-vs-seconds plot (default: ~15 per stage; 0: off)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--init-points", type=_positive_int, default=5000,
                   help="random initial points of dngaussian/3dgs and of reings without EHPS (DNGaussian LLFF: ~5000)")
    r.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], default=None,
                   help="maximum SH degree (default: 0 with --preset quick; with paper 1 for reings "
                        "(model-size study, docs/results.md) and 3 for the baselines)")
    r.add_argument("--ivps-depth", choices=["expected", "hard"], default="expected",
                   help="IVPS depth: 'expected' (normal render depth/alpha, default) or 'hard' (paper Eq. 5 literally)")
    r.add_argument("--extent", choices=["sfm", "frusta"], default="sfm",
                   help="scene box for EHPS and random inits: SfM of the training views (falls back to their "
                        "frusta) or the training frusta directly")
    r.add_argument("--cvps-fraction", type=_fraction, default=0.2,
                   help="CVPS: fraction of the fine-stage Gaussians kept (default 0.2 from the model-size "
                        "study, docs/results.md; the paper's value is 0.4)")
    r.add_argument("--max-gaussians", type=_positive_int, default=None,
                   help="cap on the Gaussian count that densification respects in every stage (default: none)")
    r.add_argument("--final-prune", type=_prune_fraction, default=0.1, metavar="FRACTION",
                   help="reings (not in the paper): after the final stage remove this fraction of the Gaussians "
                        "with the lowest importance Omega_G (Eq. 7, training views only) before evaluation; "
                        "in [0, 1), 0 = off; default 0.1 (the model-size study: no PSNR loss, docs/results.md)")
    r.add_argument("--prune-curve", action="store_true",
                   help="study/reporting: also evaluate test PSNR/SSIM of the final model cut to its top "
                        "100%%, 90%%, ..., 40%% by training-view Omega_G (metrics.json prune_curve); the test "
                        "views are used only for this report, never to rank or select, and the reported "
                        "model is unchanged")
    r.add_argument("--depth-smooth", type=_nonneg_float, default=None, metavar="WEIGHT",
                   help="weight of DNGaussian's edge-aware depth smoothness in the depth passes "
                        "(default: the recipe's 0.1 from the middle of each stage, but 0 with the stereo prior, "
                        "where it showed no benefit, docs/results.md; 0 = off)")
    r.add_argument("--factor", type=_positive_int, default=8, help="LLFF image downsampling factor")
    r.add_argument("--no-lpips", action="store_true", help="skip LPIPS (and AVGE)")
    r.add_argument("--quiet", action="store_true", help="no progress bars or stage lines")
    for k, what in (("ehps", "EHPS coarse init (random points instead)"),
                    ("ivps", "IVPS re-initialisation (fine stage starts from the coarse Gaussians)"),
                    ("cvps", "CVPS re-initialisation (final stage starts from the fine Gaussians)")):
        r.add_argument(f"--no-{k}", action="store_true", help=f"ablation: no {what}; applies to {methods_flag} reings")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="reings", description="Few-shot 3D Gaussian splatting (ReInGS) on OpenCL.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("devices", help="list OpenCL devices with versions and capabilities")
    d.add_argument("--json", action="store_true", help="machine-readable output")
    d.set_defaults(func=_cmd_devices)

    b = sub.add_parser("bench", help="kernel microbenchmarks (run `reings bench --help`)", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_cmd_bench)

    r = sub.add_parser("run", help="fit one scene and evaluate its test views (docs/pipeline.md)")
    r.add_argument("--method", default="reings",
                   help="reings | dngaussian | 3dgs, or an ablation: reings-no-ehps, reings-no-ivps, reings-no-cvps")
    r.add_argument("--data", default=None, help="scene folder; omitted: the built-in procedural scene")
    r.add_argument("--dataset", default=None, choices=["llff", "dtu", "colmap", "blender", "procedural"])
    r.add_argument("--views", type=int, default=3, help="number of training views (>= 2)")
    r.add_argument("--out", required=True, help="output folder (a rerun resumes an interrupted run there)")
    r.add_argument("--overwrite", action="store_true", help="redo a finished run in --out (starts over)")
    _add_common_fit_args(r, "--method")
    r.set_defaults(func=_cmd_run)

    e = sub.add_parser("eval", help="run every scene x view count x method of a dataset and tabulate (docs/pipeline.md)")
    e.add_argument("--dataset", default=None, choices=["llff", "dtu", "colmap", "blender", "procedural"],
                   help="dataset of the scenes under --root (default: detected per scene)")
    e.add_argument("--root", default=None, help="folder of scene folders (e.g. nerf_llff_data/)")
    e.add_argument("--scenes", default=None, help="comma list of scene folder names (default: every scene under --root)")
    e.add_argument("--views", default="3", help="comma list of training-view counts, e.g. 2,3,4")
    e.add_argument("--methods", "--method", dest="methods", default="reings",
                   help="comma list: reings, dngaussian, 3dgs, reings-no-ehps, reings-no-ivps, reings-no-cvps, ...")
    e.add_argument("--out", required=True, help="results folder: one run folder per dataset/method/views/scene")
    e.add_argument("--table-only", action="store_true", help="only rebuild results.json/results.md from the runs in --out")
    e.add_argument("--prepare-only", action="store_true",
                   help="only fill the depth-prior and SfM caches of every scene x view count (no training)")
    e.add_argument("--keep-going", action="store_true", help="go on with the other runs when one fails")
    _add_common_fit_args(e, "--methods")
    e.set_defaults(func=_cmd_eval)

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
    except (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError, PermissionError,
            ValueError) as e:
        print(f"reings: error: {e}", file=sys.stderr)
        return 2
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
