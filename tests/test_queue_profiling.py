"""The queue's profiling timestamps (reings/backends/opencl/device.py `queue_profiling`): off by
default (docs/perf_notes.md §12: NVIDIA's OpenCL spends time on every profiled command), on where
kernel times are read (REINGS_QUEUE_PROFILING=1, `set_queue_profiling(True)`: `reings bench`, the
bench scripts, kernel_census). The setting may change how long a run takes, never what it computes:
a device-engine fit gives the same bytes with and without it, each in a fresh process (the handle
is chosen when the device first opens)."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r"""
import sys, numpy as np
sys.path.insert(0, sys.argv[3])  # tests/ (cases)
from cases import dngaussian_fit_case
from reings.backends import get_backend
from reings.train import fit

scene, init, cfg = dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1,
                                       iterations=13, soft_depth_from=3, densify_until=15)
be = get_backend(sys.argv[1])
r = fit(scene, cfg, device=sys.argv[1], init=init, depth_targets=list(scene.depths), engine="device", log_every=5)
be.render(r.gaussians, scene.cameras[0])
np.savez(sys.argv[2], profiling=be.handle.profiling, stages=len(be.last_profile),
         **{k: np.asarray(getattr(r.gaussians, k)) for k in ('means', 'quats', 'log_scales', 'opacity_logits', 'sh')})
"""


def _child(device: str, tmp_path, env_value: str | None):
    out = str(tmp_path / f"fit_{env_value}.npz")
    env = dict(os.environ)
    env.pop("REINGS_QUEUE_PROFILING", None)
    if env_value is not None:
        env["REINGS_QUEUE_PROFILING"] = env_value
    env["PYTHONPATH"] = REPO + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-c", CHILD, device, out, os.path.join(REPO, "tests")], env=env,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    return np.load(out)


def test_profiling_is_off_by_default_and_changes_no_bit(device, tmp_path):
    off = _child(device, tmp_path, None)
    on = _child(device, tmp_path, "1")
    assert not bool(off["profiling"]) and bool(on["profiling"])
    assert int(off["stages"]) == 0  # no timestamps to fold: last_profile stays empty
    assert int(on["stages"]) > 0  # render's stage times (project_fwd, rasterize_fwd, ...)
    keys = [k for k in off.files if k not in ("profiling", "stages")]
    assert keys
    for k in keys:
        np.testing.assert_array_equal(off[k], on[k], err_msg=k)


def test_setting_and_environment():
    from reings.backends.opencl import device as D

    old = os.environ.pop("REINGS_QUEUE_PROFILING", None)
    try:
        D.set_queue_profiling(None)
        assert D.queue_profiling() is False
        for v, want in (("1", True), ("on", True), ("0", False), ("off", False), ("", False)):
            os.environ["REINGS_QUEUE_PROFILING"] = v
            assert D.queue_profiling() is want, v
        D.set_queue_profiling(True)  # the process's choice wins over the environment
        assert D.queue_profiling() is True
        D.set_queue_profiling(False)
        os.environ["REINGS_QUEUE_PROFILING"] = "1"
        assert D.queue_profiling() is False
    finally:
        D.set_queue_profiling(None)
        if old is None:
            os.environ.pop("REINGS_QUEUE_PROFILING", None)
        else:
            os.environ["REINGS_QUEUE_PROFILING"] = old


def test_a_backends_objects_share_its_queue(device):
    """The loss kernels a backend builds get its handle, not one opened from the spec: a fresh backend,
    the setting flipped before its loss kernels are first built (opened from the spec they would get
    another context and queue, with no order against the backend's)."""
    from reings.backends.opencl import device as D
    from reings.backends.opencl.backend import OpenCLBackend

    be = OpenCLBackend(device)
    D.set_queue_profiling(not be.handle.profiling)
    try:
        vw, ph, dl = be.view_warp_kernels, be.photometric_kernels, be.depth_loss_kernels
    finally:
        D.set_queue_profiling(None)
    assert vw.handle is be.handle and ph.handle is be.handle and dl.handle is be.handle
