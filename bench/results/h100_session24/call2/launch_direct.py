"""Kernel launches: `enqueue(queue, k, global, local, *args)`, the one way host code starts a kernel.

pyopencl's `k(queue, global, local, *args)` sets the arguments (the typed invoker of
`program.typed_invoker`) and calls clEnqueueNDRangeKernel asking for an event, which it wraps in a
Python `Event` and, when the caller drops it, releases again. The training loop never uses those
events (one in-order queue orders its commands; the host syncs on reads and `finish`), but on
NVIDIA's OpenCL an event is not free (docs/perf_notes.md §18): a run of a fern scene enqueues about
a million kernels, one at a time from Python, and a GPU step that takes ~1 ms of kernels is bound
by the host's cost per launch.

`enqueue` sets the arguments through the same typed invoker (`k.set_args`) and then calls
clEnqueueNDRangeKernel itself through ctypes, from the same OpenCL library pyopencl loaded, with no
event (OpenCL allows a NULL event pointer). It returns None there; everything that reads an event
of a launch (profiling: `reings.backends.set_queue_profiling`, the kernel census, `fit(profile=)`)
runs on a profiling queue, where `enqueue` keeps pyopencl's path and returns its event. A launch
with a wait list, an empty range, or without the library found also takes pyopencl's path.

The switch: REINGS_LAUNCH=direct (the default) | pyopencl, read when the module is imported, or
`set_launch_mode`. Both give the same commands in the same order, so the same results bit for bit
(tests/test_launch.py). Tools that count or stub launches (`harness.ClCalls`, `launches_stubbed`,
bench/host_wait.py) wrap `direct_launch` as well as pyopencl's entry point.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import struct

MODES = ("direct", "pyopencl")
_mode = os.environ.get("REINGS_LAUNCH", "direct")
if _mode not in MODES:
    raise ValueError(f"REINGS_LAUNCH must be one of {MODES}, got {_mode!r}")

_SIZES = {d: struct.Struct(f"@{d}N") for d in (1, 2, 3)}  # size_t[d], native byte order
_lib = None  # the ctypes function clEnqueueNDRangeKernel, or False when unavailable
_queues: dict[int, tuple] = {}  # id(queue) -> (queue, direct?)


def set_launch_mode(mode: str) -> str:
    """Set the launch path ("direct" or "pyopencl") for every later launch; returns the previous."""
    global _mode
    if mode not in MODES:
        raise ValueError(f"launch mode must be one of {MODES}, got {mode!r}")
    prev, _mode = _mode, mode
    _queues.clear()
    return prev


def launch_mode() -> str:
    return _mode


def _opencl_library_path() -> str | None:
    """The OpenCL library this process's pyopencl is linked to (its own ICD loader in the wheel,
    else the system's): from /proc/self/maps where there is one, else the loader's usual name."""
    import pyopencl._cl  # noqa: F401  (loads the library)

    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.split()[-1] if len(line.split()) >= 6 else ""
                if "libOpenCL" in os.path.basename(path) and os.path.isfile(path):
                    return path
    except OSError:
        pass
    return ctypes.util.find_library("OpenCL")


def _load():
    global _lib
    path = _opencl_library_path()
    try:
        lib = ctypes.PyDLL(path) if path else None  # PyDLL: the call keeps the GIL (no hand-off per launch)
        fn = lib.clEnqueueNDRangeKernel if lib is not None else None
    except (OSError, AttributeError):
        fn = None
    if fn is None:
        _lib = False
        return
    fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_char_p,
                   ctypes.c_char_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    fn.restype = ctypes.c_int32
    _lib = fn


def direct_available() -> bool:
    """Whether clEnqueueNDRangeKernel could be found for the direct path."""
    if _lib is None:
        _load()
    return bool(_lib)


def _direct(queue) -> bool:
    hit = _queues.get(id(queue))
    if hit is None or hit[0] is not queue:
        import pyopencl as cl

        ok = (_mode == "direct" and direct_available()
              and not queue.properties & cl.command_queue_properties.PROFILING_ENABLE)
        hit = _queues[id(queue)] = (queue, ok)
    return hit[1]


class LaunchError(RuntimeError):
    """clEnqueueNDRangeKernel failed on the direct path; the message names the kernel and the status."""


def direct_launch(queue, k, global_size: tuple, local_size) -> None:
    """clEnqueueNDRangeKernel(queue, k, global_size, local_size) with the arguments already set and
    no event."""
    d = len(global_size)
    pack = _SIZES[d].pack
    err = _lib(queue.int_ptr, k.int_ptr, d, None, pack(*global_size),
               None if local_size is None else pack(*local_size), 0, None, None)
    if err:
        import pyopencl as cl

        names = {v: n for n, v in vars(cl.status_code).items() if isinstance(v, int)}
        raise LaunchError(f"clEnqueueNDRangeKernel({k.function_name}, global {tuple(global_size)}, local "
                          f"{local_size}) failed: {names.get(err, err)}")


def enqueue(queue, k, global_size: tuple, local_size, *args, wait_for=None):
    """Launch kernel `k` on `queue` over `global_size` (tuple) in work-groups of `local_size`
    (tuple, or None: the implementation's choice) with `args` (numpy scalars of the kernel's types
    and memory objects; `program.typed_invoker` has given `k` its typed invoker). Returns
    pyopencl's event on its path, None on the direct path (module docstring). `wait_for`: events
    (None entries, the direct path's, are left out: the in-order queue has ordered them)."""
    if wait_for is not None:
        wait_for = [e for e in wait_for if e is not None] or None
    if wait_for or not _direct(queue) or not all(global_size):
        return k(queue, global_size, local_size, *args, wait_for=wait_for)
    k.set_args(*args)
    direct_launch(queue, k, global_size, local_size)
    return None
