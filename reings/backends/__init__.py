"""Backend registry: the one place that resolves a device string (imports lazily, one backend per
string). Everything else asks the backend it returns: what it can do is its attributes and methods
(the `Backend` protocol of reings/backends/base.py: `engines`, `trainer`, the host losses), never a
comparison of device strings.

    "reference"                          float64 numpy (reings.backends.reference)
    "pocl" | "cuda" | "cuda:N" | "oclgrind" | "opencl:P:D"   OpenCL (reings.backends.opencl.backend)

Layers: nothing here imports an engine module (reings.train, densify, state, optim, losses,
pipeline, evaluate); every kernel's host code and every float64 twin lives here
(tests/test_imports.py::test_layering).
"""
from __future__ import annotations

_CACHE: dict[str, object] = {}


def get_backend(device: str = "pocl"):
    """The backend of a device string (cached): ReferenceBackend or OpenCLBackend."""
    if not isinstance(device, str):
        raise TypeError(f"device must be a string, got {type(device).__name__}")
    b = _CACHE.get(device)
    if b is None:
        if device == "reference":
            from .reference import ReferenceBackend

            b = ReferenceBackend()
        else:
            from .opencl.backend import OpenCLBackend

            b = OpenCLBackend(device)
        _CACHE[device] = b
    return b


def set_queue_profiling(on: bool | None) -> None:
    """Whether OpenCL queues opened from now on in this process record profiling timestamps (the
    kernel times of `reings bench` and the bench scripts); off by default, since
    NVIDIA's OpenCL spends time on every profiled command (docs/perf_notes.md §12). None: back to
    REINGS_QUEUE_PROFILING. A backend already made keeps its queue."""
    from .opencl.device import set_queue_profiling as _set

    _set(on)
