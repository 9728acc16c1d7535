"""Backend registry: the one place that maps device strings to backend classes (imports lazily).

    "reference"                          float64 numpy (reings.backends.reference)
    "pocl" | "cuda" | "cuda:N" | "oclgrind" | "opencl:P:D"   OpenCL (reings.backends.opencl.backend)
"""
from __future__ import annotations

_CACHE: dict[str, object] = {}


def get_backend(device: str = "pocl"):
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
