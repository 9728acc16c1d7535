"""register_nvidia_icd (issue 14 item 24): NVIDIA's OpenCL library present without an ICD file is
registered for the process; every other case is left alone. Fake folders stand in for the system
ones (the GPU machine is where the real case happens)."""
from __future__ import annotations

import os

from reings.backends.opencl.icd import register_nvidia_icd


def _layout(tmp_path, icds: dict, lib: bool):
    vendors = tmp_path / "vendors"
    vendors.mkdir(parents=True)
    for name, text in icds.items():
        (vendors / name).write_text(text)
    libdir = tmp_path / "lib64"
    libdir.mkdir()
    if lib:
        (libdir / "libnvidia-opencl.so.1").write_bytes(b"\x7fELF")
    return str(vendors), (str(libdir),)


def test_registers_an_unregistered_nvidia_library(tmp_path, monkeypatch):
    monkeypatch.delenv("LD_LIBRARY_PATH", raising=False)
    vendors, dirs = _layout(tmp_path, {"pocl.icd": "libpocl.so.2\n"}, lib=True)
    env = {}
    d = register_nvidia_icd(env, vendors, dirs)
    assert d and env["OCL_ICD_VENDORS"] == d
    assert sorted(os.listdir(d)) == ["nvidia.icd", "pocl.icd"]
    assert open(os.path.join(d, "nvidia.icd")).read().strip() == os.path.join(dirs[0], "libnvidia-opencl.so.1")
    assert open(os.path.join(d, "pocl.icd")).read() == "libpocl.so.2\n"


def test_leaves_other_cases_alone(tmp_path, monkeypatch):
    monkeypatch.delenv("LD_LIBRARY_PATH", raising=False)
    vendors, dirs = _layout(tmp_path, {"nvidia.icd": "libnvidia-opencl.so.1\n"}, lib=True)
    assert register_nvidia_icd({}, vendors, dirs) is None  # already registered
    env = {"OCL_ICD_VENDORS": "/somewhere"}
    assert register_nvidia_icd(env, vendors, dirs) is None and env == {"OCL_ICD_VENDORS": "/somewhere"}
    vendors2, dirs2 = _layout(tmp_path / "b", {"pocl.icd": "libpocl.so.2\n"}, lib=False)
    assert register_nvidia_icd({}, vendors2, dirs2) is None  # no NVIDIA library: nothing to register
