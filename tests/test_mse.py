"""kernels/mse.cl (the train PSNR's mean squared error, `Trainer.read_mse`) against its float64 twin
reference_loss.mse_rows / mse, and the twin, the kernel's row sums and both trainers' read_mse against
an independent reference (per-pixel Python float differences, exact sums by math.fsum) and hand cases.

Tolerance: with cl_khr_fp64 the kernel's differences, squares and row sums are double, as numpy's,
so only the order of the additions differs (rtol 1e-12); without it float sums (rtol 1e-5)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from reings.backends import get_backend
from reings.backends import reference_loss as R

pytest.importorskip("pyopencl")


class _Frame:
    """The frame fields read_mse reads: its size and its image buffer."""

    def __init__(self, h, w, buf):
        self.height, self.width, self.bufs = h, w, {"out_rgb": buf}


def _mse_fsum(x, y) -> tuple[float, np.ndarray]:
    """An independent reference: (the mean, per-row sums) of (x - y)^2 with each difference and
    square taken on Python floats (double) and the sums exact (math.fsum)."""
    xs, ys = np.asarray(x).tolist(), np.asarray(y).tolist()
    rows = [math.fsum((float(a) - float(b)) ** 2 for pa, pb in zip(rx, ry) for a, b in zip(pa, pb))
            for rx, ry in zip(xs, ys)]
    return math.fsum(rows) / np.asarray(x).size, np.array(rows)


def test_mse_twin(rng):
    x = rng.uniform(size=(7, 5, 3)).astype(np.float32)
    y = rng.uniform(size=(7, 5, 3))
    rows = R.mse_rows(x, y)
    assert rows.shape == (7,) and rows.dtype == np.float64
    want, want_rows = _mse_fsum(x, y)
    np.testing.assert_allclose(rows, want_rows, rtol=1e-14)
    assert R.mse(x, y) == pytest.approx(want, rel=1e-14)
    assert rows.sum() / x.size == pytest.approx(want, rel=1e-14)
    assert R.mse(x, x) == 0.0
    # a hand case: every difference 0.5 (exact in float32), so the error is 0.25 exactly
    assert R.mse(np.zeros((2, 3, 3), np.float32), np.full((2, 3, 3), 0.5)) == 0.25


@pytest.mark.parametrize("shape", [(1, 1), (15, 17), (40, 23), (378, 504)])
def test_mse_kernel_matches_twin(device, shape, rng):
    h, w = shape
    gt = rng.uniform(size=(h, w, 3)).astype(np.float32)
    x = np.clip(gt + rng.normal(scale=0.1, size=gt.shape), 0, 1).astype(np.float32)
    x[0, 0] = gt[0, 0]  # an exact pixel
    other = rng.uniform(size=(h, w, 3)).astype(np.float32)
    t = get_backend(device).trainer([other, gt], engine="device")
    buf = t.mem.get("pixel", "test_rgb", h * w, 12)
    t._write(buf, x)
    got = t.read_mse(_Frame(h, w, buf), 1)
    want = R.mse(x, gt)
    rtol = 1e-12 if t.fp64 else 1e-5
    assert got == pytest.approx(want, rel=rtol)
    if h * w <= 40 * 23:  # the kernel's own row sums against exact per-row sums (not the twin)
        ref, ref_rows = _mse_fsum(x, gt)
        np.testing.assert_allclose(t._read(t.mem.get("small", "mse_rows", h, np.dtype(t.real).itemsize), (h,), t.real),
                                   ref_rows, rtol=rtol)
        assert got == pytest.approx(ref, rel=rtol)
    assert t.read_mse(_Frame(h, w, buf), 0) == pytest.approx(R.mse(x, other), rel=rtol)
    t._write(buf, gt)
    assert t.read_mse(_Frame(h, w, buf), 1) == 0.0


def test_host_trainer_read_mse(rng):
    gt = rng.uniform(size=(6, 9, 3))
    t = get_backend("reference").trainer([gt, np.full((6, 9, 3), 0.75)], engine="host")

    class _Out:
        rgb = rng.uniform(size=(6, 9, 3)).astype(np.float32)

    class _Fr:
        out = _Out

    assert t.read_mse(_Fr, 0) == pytest.approx(_mse_fsum(_Out.rgb, gt)[0], rel=1e-14)
    _Out.rgb = np.full((6, 9, 3), 0.25, np.float32)
    assert t.read_mse(_Fr, 1) == 0.25  # every difference 0.5


_OCLGRIND_SCRIPT = """
import types
import numpy as np
import pyopencl as cl
from reings.backends import get_backend
from reings.backends import reference_loss as R
h, w = 5, 7
rng = np.random.default_rng(0)
gt = rng.uniform(size=(h, w, 3)).astype(np.float32)
x = rng.uniform(size=(h, w, 3)).astype(np.float32)
tr = get_backend("oclgrind").trainer([gt], engine="device")
buf = cl.Buffer(tr.handle.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
got = tr.read_mse(types.SimpleNamespace(width=w, height=h, bufs={"out_rgb": buf}), 0)
assert abs(got - R.mse(x, gt)) <= 1e-5 * R.mse(x, gt)
print("ok")
"""


@pytest.mark.oclgrind
def test_oclgrind_checks():
    """mse_rows under Oclgrind's checks."""
    from oclgrind_util import check_script

    check_script(_OCLGRIND_SCRIPT)
