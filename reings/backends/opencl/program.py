"""KernelLibrary: finds `kernels/`, builds each .cl once per (file, defines), hands out kernels.

The kernel directory is the installed `reings/_kernels` (wheel layout) or, in a source checkout,
the repository's `kernels/`. Every build gets `-I <kernels>` (pyopencl's cache hashes included
headers) and the device's capability defines from `quirks.build_defines`. Fast-math options are
never used: the NaN/Inf guards in the kernels rely on IEEE comparisons. The files that must match
numpy's float32 arithmetic bit for bit (`CORRECTLY_ROUNDED`: the optimizer, the penalty
gradients, the densification statistics and the SH packing of the training state) are built with
`-cl-fp32-correctly-rounded-divide-sqrt` where the device offers it (OpenCL otherwise allows
2.5-3 ulp division and sqrt, and NVIDIA's OpenCL uses that latitude).

`typed_invoker` gives a kernel object pyopencl's fast launch path; every kernel's host code (the
backend, the device trainer, the loss classes) launches through it.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

from . import quirks


CORRECTLY_ROUNDED = frozenset({"adam.cl", "regularize.cl", "densify_accumulate.cl"})


def has_correctly_rounded_divide_sqrt(device) -> bool:
    import pyopencl as cl

    try:
        return bool(device.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)
    except Exception:  # an ICD without the query
        return False


class KernelBuildError(RuntimeError):
    """A .cl file failed to compile; the message names the file and carries the build log."""


def kernel_dir() -> Path:
    here = Path(__file__).resolve()
    installed = here.parents[2] / "_kernels"  # reings/_kernels
    if installed.is_dir():
        return installed
    repo = here.parents[3] / "kernels"  # <repo>/kernels
    if repo.is_dir():
        return repo
    raise FileNotFoundError(f"reings kernels not found (looked in {installed} and {repo})")


class KernelLibrary:
    """Per-context cache of built programs. `get(file, kernel, **defines)` returns a cl.Kernel
    (a fresh kernel object per call site is the caller's business: keep it and reuse it)."""

    def __init__(self, context, device):
        self.context = context
        self.device = device
        self.dir = kernel_dir()
        self.base_defines = quirks.build_defines(device)
        self.correct_div_sqrt = has_correctly_rounded_divide_sqrt(device)
        self._programs: dict[tuple, object] = {}
        # programs built by this library and their wall seconds (pyopencl's and the driver's caches
        # included: a warm cache makes a build cheap); pipeline.kernel_builds reports them per run
        self.builds = 0
        self.build_seconds = 0.0
        self._count_lock = threading.Lock()  # builds may run in threads (bench/bench_builds.py replay)

    def options(self, defines: dict, filename: str | None = None) -> list[str]:
        d = dict(self.base_defines)
        d.update(defines)
        opts = [f"-I{self.dir}"]  # a list element, so a path with spaces needs no quoting
        opts += [f"-D{k}={int(v) if isinstance(v, bool) else v}" for k, v in sorted(d.items())]
        if filename in CORRECTLY_ROUNDED and self.correct_div_sqrt:
            opts.append("-cl-fp32-correctly-rounded-divide-sqrt")
        extra = os.environ.get("REINGS_CL_BUILD_OPTIONS")
        if extra:
            opts += extra.split()
        return opts

    def program(self, filename: str, **defines):
        import pyopencl as cl

        key = (filename, tuple(sorted(defines.items())))
        prg = self._programs.get(key)
        if prg is None:
            path = self.dir / filename
            if not path.is_file():
                raise FileNotFoundError(f"kernel source {path} does not exist")
            src = path.read_text()
            t = time.perf_counter()
            try:
                with _compiler_output() as said:
                    prg = cl.Program(self.context, src).build(options=self.options(defines, filename),
                                                              devices=[self.device])
            except cl.RuntimeError as e:  # build failure: show the log with the file name
                raise KernelBuildError(f"building {path} with {self.options(defines, filename)} failed:\n{e}"
                                       + (f"\ncompiler output:\n{said[0]}" if said and said[0] else "")) from e
            with self._count_lock:
                self.builds += 1
                self.build_seconds += time.perf_counter() - t
            self._programs[key] = prg
        return prg

    def get(self, filename: str, kernel: str, **defines):
        """A new kernel object of `kernel` (its own argument state; pyopencl warns when the same
        program's attribute is fetched twice, e.g. by two rasterizers sharing a program)."""
        import pyopencl as cl

        return cl.Kernel(self.program(filename, **defines), kernel)


@contextlib.contextmanager
def _compiler_output():
    """Hold back what the OpenCL compiler prints during a build (PoCL's clang writes warnings to
    the process's stderr; pyopencl turns a non-empty build log into a CompilerWarning): a
    successful build is silent; the captured text is yielded (list of one string, filled on exit)
    for a failed build's error. REINGS_CL_VERBOSE=1 lets everything through."""
    import warnings

    said: list[str] = []
    if os.environ.get("REINGS_CL_VERBOSE"):
        yield said
        return
    import tempfile

    try:
        fd = sys.stderr.fileno()
    except (AttributeError, ValueError, OSError):  # no real stderr (e.g. captured): nothing to hold back
        fd = None
    if fd is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield said
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                yield said
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            said.append(tmp.read().decode("utf-8", "replace"))


_LIBS: dict[int, KernelLibrary] = {}


def library_for(handle) -> KernelLibrary:
    """The KernelLibrary of a DeviceHandle (one per context)."""
    lib = _LIBS.get(id(handle.context))
    if lib is None:
        lib = _LIBS[id(handle.context)] = KernelLibrary(handle.context, handle.device)
    return lib


def typed_invoker(k, args) -> None:
    """Give kernel `k` pyopencl's typed invoker, the scalar dtypes taken from `args` (numpy scalars
    -> their dtype, anything else -> a memory object), once per kernel object. Why: pyopencl's
    generic invoker sets a numpy-scalar argument through a slow path (~6.5 us each, measured with
    pyopencl 2026.1 on Zen 5; ~50 us for a 9-scalar launch) where the typed invoker packs them all
    in ~1 us. Callers pass numpy scalars of the kernel's exact types (as the generic path needs
    anyway), so the inferred types are the kernel's. A call with a plain Python number leaves the
    kernel generic (its type is not known)."""
    if any(isinstance(a, (int, float)) and not isinstance(a, np.generic) for a in args):
        return
    k.set_scalar_arg_dtypes([a.dtype if isinstance(a, np.generic) else None for a in args])
    k._reings_typed = True
