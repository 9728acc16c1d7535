"""The device engine's small kernels against their numpy references:

    kernels/adam.cl adam_step      vs reings.optim.Adam (numpy) and the float64 torch.optim.Adam
                                   step of tests/test_adam.py, per-group lrs and step counts,
                                   strided SH gradients with inactive coefficients
    kernels/regularize.cl          vs reings.losses.regularizers (reference_loss.regularize_fwd_bwd):
                                   the gradients, and the value (regularize_value, logging)
    kernels/densify_accumulate.cl  vs reings.densify.accumulate(ndc_grad_norm(...))

Tolerance "float32 rounding": a few ulps of the values compared (the kernels mirror numpy's float32
operation sequence; where sqrt / division are not correctly rounded on a device the results
differ by ulps, never by a step)."""
from __future__ import annotations

import numpy as np
import pytest

from reings import densify as D
from reings.backends import get_backend
from reings.losses import regularizers
from reings.optim import Adam
from reings.state import PARAM_NAMES, TrainState
from reings.types import Gaussians

from test_adam import _ref_adam

pytest.importorskip("pyopencl")


def _state(rng, n=257, k=16):
    g = Gaussians(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                  rng.normal(-2, 0.7, size=(n, 3)).astype(np.float32), rng.normal(-1, 2, size=n).astype(np.float32),
                  rng.normal(size=(n, k, 3)).astype(np.float32))
    st = TrainState.from_gaussians(g)
    D.init_stats(st)
    return st


def _trainer(device, st, adam):
    t = get_backend(device).trainer([], engine="device", adam=adam)
    t.upload(st)
    return t


def _grad_buffers(t, host: dict, sh_k: int) -> dict:
    """Device gradient buffers like backend.backward_device's, from host arrays."""
    out = {}
    for f, a in host.items():
        buf = t.mem.get("gauss", "test_g_" + f, a.shape[0], max(a[0].nbytes, 1))
        t._write(buf, a)
        out[f] = buf
    out["sh_k"] = sh_k
    return out


def _ulps(a, b):
    """Distance in float32 ulps (of the larger magnitude), elementwise."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    sp = np.spacing(np.maximum(np.abs(a), np.abs(b)).astype(np.float32))
    return np.abs(a.astype(np.float64) - b.astype(np.float64)) / sp


@pytest.mark.parametrize("location", ["kernel", "numpy"])
def test_adam_kernel_matches_numpy_adam(device, rng, location):
    """Several steps with per-group lrs and separate step counts (means stepped three times per
    iteration, opacities and SH DC twice, the others once), SH at an active degree below the maximum (sh_rest's
    inactive coefficients get zero gradient: values and moments must stay put)."""
    n, kmax, sh_k = 257, 16, 4
    st = _state(rng, n, kmax)
    host = TrainState.from_arrays(st.to_arrays())  # an independent copy for the numpy Adam
    lrs = {"means": 0.016, "quats": 0.001, "log_scales": 0.005, "opacity_logits": 0.05, "sh_dc": 0.0025,
           "sh_rest": 0.000125}
    t = _trainer(device, st, location)
    opt_dev = Adam(st.params, lrs, state=st.adam)  # lrs / betas / eps / step counts for the device
    opt_host = Adam(host.params, lrs, state=host.adam)
    p0 = {k: v.copy() for k, v in host.params.items()}
    seq = {k: [] for k in PARAM_NAMES}
    for it in range(6):
        passes = [("means",), ("means", "sh_dc"), ("opacity_logits",), tuple(PARAM_NAMES)]
        for groups in passes:
            scale = 10.0 ** rng.uniform(-6, 1)  # gradients over many magnitudes
            g = {"means": rng.normal(size=(n, 3)), "quats": rng.normal(size=(n, 4)),
                 "log_scales": rng.normal(size=(n, 3)), "opacity_logits": rng.normal(size=n),
                 "sh": rng.normal(size=(n, sh_k, 3))}
            g = {k: (v * scale).astype(np.float32) for k, v in g.items()}
            g["means"][::7] = 0.0  # invisible rows: exactly zero gradient
            full_sh = np.zeros((n, kmax, 3), np.float32)
            full_sh[:, :sh_k] = g["sh"]
            hg = {"means": g["means"], "quats": g["quats"], "log_scales": g["log_scales"],
                  "opacity_logits": g["opacity_logits"], "sh_dc": full_sh[:, :1], "sh_rest": full_sh[:, 1:]}
            opt_host.step({k: hg[k] for k in groups})
            t.adam_step(opt_dev, _grad_buffers(t, g, sh_k), groups)
            for k in groups:
                seq[k].append(hg[k])
    assert opt_dev.state.step == opt_host.state.step == {
        "means": 18, "quats": 6, "log_scales": 6, "opacity_logits": 12, "sh_dc": 12, "sh_rest": 6}
    t.download(st)
    for k in PARAM_NAMES:
        for a, b, what in ((st.params[k], host.params[k], "param"), (st.adam.exp_avg[k], host.adam.exp_avg[k], "m"),
                           (st.adam.exp_avg_sq[k], host.adam.exp_avg_sq[k], "v")):
            assert a.shape == b.shape
            u = _ulps(a, b)
            assert u.max() <= 8, f"{location} {k} {what}: {u.max()} ulps from numpy Adam"
        if location == "numpy":  # the same numpy code on mapped buffers: bit-identical
            np.testing.assert_array_equal(st.params[k], host.params[k])
    # inactive SH coefficients (rows sh_k-1.. of sh_rest) are untouched, their moments zero
    np.testing.assert_array_equal(st.params["sh_rest"][:, sh_k - 1:], p0["sh_rest"][:, sh_k - 1:])
    assert not np.any(st.adam.exp_avg["sh_rest"][:, sh_k - 1:])
    # and both agree with the float64 torch.optim.Adam step
    for k in ("means", "opacity_logits", "sh_dc"):
        ref, _, _ = _ref_adam(p0[k], seq[k], lrs[k])
        np.testing.assert_allclose(st.params[k], ref, rtol=0, atol=2e-6 + 1e-6 * np.abs(ref).max())


@pytest.mark.parametrize("chunk", [None, 8, 3])
def test_regularizer_kernel_matches_numpy(device, rng, chunk, monkeypatch):
    """chunk: regularize_opacity_count's Gaussians per work-item (None: this device's; 8 is the GPUs',
    3 leaves a partial last chunk of the 1000)."""
    if chunk is not None:
        from reings.backends.opencl import trainer as T

        monkeypatch.setattr(T, "REG_COUNT_CHUNK_CPU", chunk)
        monkeypatch.setattr(T, "REG_COUNT_CHUNK_GPU", chunk)
    n = 1000
    st = _state(rng, n, 1)
    ls = st.params["log_scales"]
    ls[:10] = ls[:10, :1]  # isotropic rows (ties: zero shape gradient)
    ls[10:20, 1] = ls[10:20, 0]  # a tie between two axes
    st.params["opacity_logits"][:5] = np.float32(np.log(0.2 / 0.8)) + np.float32(0.3)
    t = _trainer(device, st, "kernel")
    g0 = {"log_scales": rng.normal(size=(n, 3)).astype(np.float32) * 1e-3,
          "opacity_logits": rng.normal(size=n).astype(np.float32) * 1e-3}
    # the opacity counts alternate between two pairs, each zeroed by the call before: counted, counted,
    # not counted, counted, counted (a pair left unzeroed would double its counts)
    for weights in ((0.002, 0.001, 0.001), (0.0, 0.0, 0.5), (0.3, 0.0, 0.0), (0.0, 0.0, 0.5), (0.0, 0.0, 0.7)):
        bufs = _grad_buffers(t, g0, 1)
        t.regularize(bufs, *weights)
        _, rg = regularizers(st.params, *weights)
        for k in g0:
            got = t._read(bufs[k], g0[k].shape, np.float32)
            want = g0[k] + rg[k] if k in rg else g0[k]
            u = _ulps(got, want)
            assert u.max() <= 4, f"{weights} {k}: {u.max()} ulps"
            assert np.any(got != g0[k]) == (k in rg)


def test_opacity_count_at_the_split(device, rng):
    """regularize_opacity_count counts o > 0.2 and o < 0.2 as numpy's float64 sigmoid does on the 4001 float logits
    around logit(0.2) = -ln 4 (where the kernel's compare with LOGIT_UNDER_SPLIT could be off by a float), NaN,
    +-inf and random logits; the opacity gradient (which divides by the counts) agrees to 4 ulps."""
    near = np.float32(-np.log(4.0)).view(np.int32) + np.arange(-2000, 2001, dtype=np.int32)
    lg = np.concatenate([near.view(np.float32), np.float32([np.nan, np.inf, -np.inf]),
                         rng.normal(-1, 2, size=97).astype(np.float32)])
    n = len(lg)
    st = _state(rng, n, 1)
    st.params["opacity_logits"][:] = lg
    o = 1.0 / (1.0 + np.exp(-lg.astype(np.float64)))
    want_counts = [int((o > 0.2).sum()), int((o < 0.2).sum())]
    assert min(want_counts) > 2000  # the window straddles the split
    t = _trainer(device, st, "kernel")
    if not t.fp64:
        pytest.skip("the compare is the build with doubles' (without them the kernel keeps the float sigmoid)")
    g0 = {"log_scales": np.zeros((n, 3), np.float32), "opacity_logits": rng.normal(size=n).astype(np.float32) * 1e-3}
    for _ in range(2):  # both pairs of counters
        pair = t._reg_pair
        bufs = _grad_buffers(t, g0, 1)
        t.regularize(bufs, 0.0, 0.0, 0.5)
        counts = t._read(t._reg_counts, (2, 2), np.int32)
        assert counts[pair].tolist() == want_counts
        _, rg = regularizers(st.params, 0.0, 0.0, 0.5)
        got = t._read(bufs["opacity_logits"], (n,), np.float32)
        want = g0["opacity_logits"] + rg["opacity_logits"]
        ok = np.isfinite(want)
        assert np.array_equal(np.isnan(got), np.isnan(want))
        assert _ulps(got[ok], want[ok]).max() <= 4


def test_regularizer_lanes_keep_the_bits(device, rng):
    """regularize_grads on 8 lanes (REG_VW 8, the CPU build: the argmax / argmin as masks, the branches as
    selects) gives the bytes of one work-item per Gaussian (REG_VW 1): 1003 Gaussians (a partial last
    work-item), ties between axes, NaN and infinite log-scales and logits, each penalty alone and all three,
    opacity counts on both sides of the split."""
    be = get_backend(device)
    if not be.cpu:
        pytest.skip("REG_VW 8 is the CPU build (GPUs run one Gaussian per work-item)")
    n = 1003
    st = _state(rng, n, 1)
    ls, lg = st.params["log_scales"], st.params["opacity_logits"]
    ls[:10] = ls[:10, :1]  # isotropic rows
    ls[10:20, 2] = ls[10:20, 0]  # ties between two axes
    ls[20, 1], ls[21, 0], ls[22, 2] = np.nan, np.inf, -np.inf
    lg[23], lg[24], lg[25] = np.nan, np.inf, -np.inf
    t = _trainer(device, st, "kernel")
    g0 = {"log_scales": rng.normal(size=(n, 3)).astype(np.float32) * 1e-3,
          "opacity_logits": rng.normal(size=n).astype(np.float32) * 1e-3}
    fp64 = int(t.fp64)
    builds = {vw: be.kernel("regularize.cl", "regularize_grads", REGULARIZE_FP64=fp64, REG_VW=vw) for vw in (1, 8)}
    old = t.reg_vw, t.k_reg_grads
    try:
        for weights in ((0.002, 0.001, 0.001), (0.3, 0.0, 0.0), (0.0, 0.01, 0.0), (0.0, 0.0, 0.5)):
            out = {}
            for vw in (1, 8):
                t.reg_vw, t.k_reg_grads = vw, builds[vw]
                bufs = _grad_buffers(t, g0, 1)
                t.regularize(bufs, *weights)
                out[vw] = {k: t._read(bufs[k], g0[k].shape, np.float32) for k in g0}
            for k in g0:
                assert np.array_equal(out[1][k].view(np.uint32), out[8][k].view(np.uint32)), (weights, k)
                moved = weights[2] > 0 if k == "opacity_logits" else weights[0] > 0 or weights[1] > 0
                assert np.any(out[1][k] != g0[k]) == moved, (weights, k)
    finally:
        t.reg_vw, t.k_reg_grads = old


@pytest.mark.parametrize("n", [0, 1, 256, 1000])
def test_regularize_value_kernel_matches_numpy(device, rng, n):
    """regularize(value=True) / read_regularize (kernels/regularize.cl regularize_value, per-chunk sums
    added in float64 by reference_loss.regularize_value) against regularize_fwd_bwd's float64 value,
    and the gradients exactly as without value=True."""
    from reings.backends.reference_loss import regularize_value, regularize_value_sums

    st = _state(rng, n, 1)
    if n >= 20:
        ls = st.params["log_scales"]
        ls[:10] = ls[:10, :1]  # isotropic rows
        ls[10:20, 1] = ls[10:20, 0]  # a tie between two axes
    t = _trainer(device, st, "kernel")
    g0 = {"log_scales": rng.normal(size=(n, 3)).astype(np.float32) * 1e-3,
          "opacity_logits": rng.normal(size=n).astype(np.float32) * 1e-3}
    rtol = 1e-12 if t.fp64 else 1e-5
    for weights in ((0.002, 0.001, 0.001), (0.0, 0.0, 0.5), (0.3, 0.0, 0.0), (0.0, 0.0, 0.0)):
        want, _ = regularizers(st.params, *weights)
        assert regularize_value(regularize_value_sums(st.params), n, *weights) == pytest.approx(want, rel=1e-12)
        with_value = _grad_buffers(t, g0, 1) if n else {}
        t.regularize(with_value, *weights, value=True)
        got = t.read_regularize()
        assert got == pytest.approx(want, rel=rtol, abs=1e-300)
        if n:
            a = {k: t._read(with_value[k], g0[k].shape, np.float32) for k in g0}
            without = _grad_buffers(t, g0, 1)
            t.regularize(without, *weights)
            for k in g0:
                np.testing.assert_array_equal(a[k], t._read(without[k], g0[k].shape, np.float32))
            assert t.read_regularize() == got  # a regularize without value keeps the last value


_REG_VALUE_OCLGRIND = """
import numpy as np
from reings import densify as D
from reings.backends import get_backend
from reings.backends.opencl.trainer import REG_VALUE_CHUNK
from reings.backends.reference_loss import REG_VALUE_COLS, regularize_value
from reings.losses import regularizers
from reings.state import TrainState
from reings.types import Gaussians
n, rng = 300, np.random.default_rng(0)  # two chunks, the second partial
g = Gaussians(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
              rng.normal(-2, 0.7, size=(n, 3)).astype(np.float32), rng.normal(-1, 2, size=n).astype(np.float32),
              rng.normal(size=(n, 1, 3)).astype(np.float32))
st = TrainState.from_gaussians(g)
D.init_stats(st)
t = get_backend("oclgrind").trainer([], engine="device", adam="kernel")
t.upload(st)
chunks = -(-n // REG_VALUE_CHUNK)
sums = t.mem.get("small", "reg_value", chunks * REG_VALUE_COLS, np.dtype(t.real).itemsize)
t._launch("regularize_value", t.k_reg_value, chunks, np.int32(n), np.int32(REG_VALUE_CHUNK),
          t.buf("p", "log_scales"), t.buf("p", "opacity_logits"), sums)
got = regularize_value(t._read(sums, (chunks, REG_VALUE_COLS), t.real), n, 0.002, 0.001, 0.001)
want = regularizers(st.params, 0.002, 0.001, 0.001)[0]
assert abs(got - want) <= 1e-5 * abs(want)
print("ok")
"""


@pytest.mark.oclgrind
def test_regularize_value_oclgrind():
    """regularize_value (the launch `regularize(value=True)` adds) under Oclgrind's checks."""
    from oclgrind_util import check_script

    check_script(_REG_VALUE_OCLGRIND)


def test_densify_accumulate_kernel_matches_numpy(device, rng):
    n = 777
    st = _state(rng, n, 1)
    host = TrainState.from_arrays(st.to_arrays())
    t = _trainer(device, st, "kernel")
    W, H = 70, 45
    from reings.backends.base import V_RECORD

    class _Fr:  # the two frame buffers densify_accumulate reads
        width, height = W, H
        bufs = {}

    for _ in range(3):
        radii = np.where(rng.random(n) < 0.6, rng.integers(1, 40, n), 0).astype(np.int32)
        vp = rng.normal(size=(n, V_RECORD)).astype(np.float32) * 1e-4
        vp[:40, :2] = rng.choice(np.float32([3e38, -1e30, 1e-40, -1e-45, 1e20, np.inf, 0.0]), (40, 2))  # extremes
        _Fr.bufs = {"radii": t.mem.get("gauss", "test_radii", n, 4), "v_proj": t.mem.get("gauss", "test_vp", n, 40)}
        t._write(_Fr.bufs["radii"], radii)
        t._write(_Fr.bufs["v_proj"], vp)
        t.accumulate(_Fr)
        v2d = np.where(radii[:, None] > 0, vp[:, :2], 0).astype(np.float32)
        D.accumulate(host, D.ndc_grad_norm(v2d, W, H), radii > 0, radii)
    t.download(st)
    np.testing.assert_array_equal(st.stats[D.COUNT], host.stats[D.COUNT])
    np.testing.assert_array_equal(st.stats[D.RADII], host.stats[D.RADII])
    if t.fuse_stats:  # the device has doubles: sqrt(x x + y y) in double, each operation IEEE-rounded, as numpy
        np.testing.assert_array_equal(st.stats[D.ACCUM].view(np.uint32), host.stats[D.ACCUM].view(np.uint32))
    else:  # float hypot: the library's last bits
        fin = np.isfinite(host.stats[D.ACCUM])
        assert _ulps(st.stats[D.ACCUM][fin], host.stats[D.ACCUM][fin]).max() <= 4
        np.testing.assert_array_equal(st.stats[D.ACCUM][~fin], host.stats[D.ACCUM][~fin])
    assert host.stats[D.ACCUM][np.isfinite(host.stats[D.ACCUM])].max() > 0
