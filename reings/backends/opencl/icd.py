"""NVIDIA's OpenCL library present but not registered (issue 14 item 24).

GPU containers often carry `libnvidia-opencl.so.1` (mounted by the NVIDIA container toolkit) but
no `/etc/OpenCL/vendors/*.icd` file naming it, so the ICD loader sees no NVIDIA platform. Before
the first platform query of the process (`device._platforms`), `register_nvidia_icd` detects
that case and registers the library for this process only: a private vendors folder holding
copies of the system's `.icd` files plus `nvidia.icd`, named by `OCL_ICD_VENDORS` (read by the
ocl-icd loader at its first call). It does nothing when `OCL_ICD_VENDORS` is already set, when an
`.icd` file already names an NVIDIA library, or when no NVIDIA library is found. The manual
remedy is the same: `echo /path/libnvidia-opencl.so.1 > DIR/nvidia.icd; export OCL_ICD_VENDORS=DIR`.
"""
from __future__ import annotations

import glob
import os
import tempfile

NVIDIA_LIB = "libnvidia-opencl.so.1"
LIB_DIRS = ("/usr/local/nvidia/lib64", "/usr/local/nvidia/lib", "/usr/lib/x86_64-linux-gnu", "/usr/lib64",
            "/usr/lib/aarch64-linux-gnu", "/usr/lib")
VENDORS = "/etc/OpenCL/vendors"


def find_nvidia_library(dirs=LIB_DIRS) -> str | None:
    """The first `libnvidia-opencl.so.1` in `dirs` (and in $LD_LIBRARY_PATH's folders), or None."""
    extra = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d]
    for d in (*extra, *dirs):
        p = os.path.join(d, NVIDIA_LIB)
        if os.path.isfile(p):
            return p
    return None


def _icd_names_nvidia(path: str) -> bool:
    try:
        with open(path) as f:
            return "nvidia" in f.read().lower()
    except OSError:
        return False


def register_nvidia_icd(env=None, vendors: str = VENDORS, dirs=LIB_DIRS) -> str | None:
    """Register NVIDIA's library for this process when it is present but unregistered (module
    doc). Returns the private vendors folder it set in `env` (default os.environ), or None."""
    env = os.environ if env is None else env
    if env.get("OCL_ICD_VENDORS"):
        return None
    icds = sorted(glob.glob(os.path.join(vendors, "*.icd")))
    if any(_icd_names_nvidia(p) for p in icds):
        return None
    lib = find_nvidia_library(dirs)
    if lib is None:
        return None
    d = tempfile.mkdtemp(prefix="reings-icd-")
    for p in icds:
        try:
            with open(p) as src, open(os.path.join(d, os.path.basename(p)), "w") as dst:
                dst.write(src.read())
        except OSError:
            continue
    with open(os.path.join(d, "nvidia.icd"), "w") as f:
        f.write(lib + "\n")
    env["OCL_ICD_VENDORS"] = d
    return d
