"""TrainState and apply_index_op: params, Adam moments and stats stay aligned through
prune / clone / split; new rows get zero moments."""
from __future__ import annotations

import numpy as np
import pytest

from reings.optim import Adam, make_optimizer
from reings.config import preset
from reings.state import TrainState, apply_index_op, reset_moments
from reings.types import Gaussians


def _gaussians(rng, n=6, deg=1):
    k = (1, 4, 9, 16)[deg]
    return Gaussians(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)) - 2,
                     rng.normal(size=n), rng.normal(size=(n, k, 3)))


def _tagged_state(rng, n=6):
    """State whose row i carries the value i in every param, moment and stat (plus a field offset)."""
    st = TrainState.from_gaussians(_gaussians(rng, n), sh_degree=3)
    for j, k in enumerate(st.params):
        shape = st.params[k].shape
        rowid = np.arange(n, dtype=np.float32).reshape((n,) + (1,) * (len(shape) - 1))
        st.params[k][...] = rowid + 100 * j
        st.adam.exp_avg[k][...] = rowid + 1000 + 100 * j
        st.adam.exp_avg_sq[k][...] = rowid + 2000 + 100 * j
        st.adam.step[k] = 7
    st.stats["grad_accum"] = np.arange(n, dtype=np.float32) + 0.5
    st.stats["denom"] = np.arange(n, dtype=np.int32) + 1
    return st


def _rows_ok(st, src):
    """Row r of everything must come from original row src[r] (or be fresh where src[r] < 0)."""
    for j, k in enumerate(st.params):
        a = st.params[k].reshape(len(st), -1)
        m = st.adam.exp_avg[k].reshape(len(st), -1)
        v = st.adam.exp_avg_sq[k].reshape(len(st), -1)
        for r, s in enumerate(src):
            if s >= 0:
                if a.shape[1]:
                    assert np.all(m[r] == s + 1000 + 100 * j), (k, r)
                    assert np.all(v[r] == s + 2000 + 100 * j), (k, r)
            else:
                assert np.all(m[r] == 0) and np.all(v[r] == 0), (k, r)
        assert st.adam.step[k] == 7
    for r, s in enumerate(src):
        assert st.stats["grad_accum"][r] == (s + 0.5 if s >= 0 else 0)
        assert st.stats["denom"][r] == (s + 1 if s >= 0 else 0)


def test_prune_keeps_alignment(rng):
    st = _tagged_state(rng)
    keep = np.array([True, False, True, True, False, True])
    apply_index_op(st, keep=keep)
    assert len(st) == 4
    _rows_ok(st, [0, 2, 3, 5])
    assert np.all(st.params["means"][:, 0] == [0, 2, 3, 5])


def test_clone_gets_zero_moments(rng):
    st = _tagged_state(rng)
    apply_index_op(st, duplicate=np.array([4, 1, 4]))
    assert len(st) == 9
    _rows_ok(st, [0, 1, 2, 3, 4, 5, -1, -1, -1])
    assert np.all(st.params["means"][6:, 0] == [4, 1, 4])  # parameters copied
    assert np.all(st.params["sh_rest"][6:, 0, 0] == [4 + 500, 1 + 500, 4 + 500])


def test_split_prune_and_append(rng):
    st = _tagged_state(rng)
    sel = np.array([False, True, False, False, True, False])
    children = {k: np.concatenate([st.params[k][sel], st.params[k][sel]]) * 0 - 7 for k in st.params}
    apply_index_op(st, keep=~sel, append=children)
    assert len(st) == 8
    _rows_ok(st, [0, 2, 3, 5, -1, -1, -1, -1])
    assert np.all(st.params["opacity_logits"][4:] == -7)
    # then a clean_views-style prune, then more clones: still aligned
    apply_index_op(st, keep=np.array([1, 2, 4, 5]), duplicate=np.array([1]))
    _rows_ok(st, [2, 3, -1, -1, -1])


def test_adam_follows_edited_rows(rng):
    """After an edit, the optimizer steps the new arrays and surviving rows keep their history."""
    g = _gaussians(rng, n=5, deg=0)
    st = TrainState.from_gaussians(g, sh_degree=1)
    opt = make_optimizer(st, preset("3dgs").optim, extent=1.0)
    grads = lambda: {k: rng.normal(size=v.shape).astype(np.float32) for k, v in st.params.items()}
    opt.step(grads())
    opt.step(grads())
    m_before = st.adam.exp_avg["means"].copy()
    apply_index_op(st, keep=np.array([True, True, False, True, True]), duplicate=np.array([0]))
    assert st.params is opt.params and st.adam is opt.state
    np.testing.assert_array_equal(st.adam.exp_avg["means"][:4], m_before[[0, 1, 3, 4]])
    assert np.all(st.adam.exp_avg["means"][4] == 0)
    opt.step(grads())
    assert st.adam.step["means"] == 3 and st.params["means"].shape == (5, 3)


def test_gaussians_view_and_grads(rng):
    g = _gaussians(rng, n=4, deg=1)
    st = TrainState.from_gaussians(g, sh_degree=3)
    assert st.params["sh_rest"].shape == (4, 15, 3) and st.max_sh_degree == 3
    g1 = st.gaussians(sh_degree=1)
    np.testing.assert_array_equal(g1.sh, g.sh)
    assert st.gaussians().sh.shape == (4, 16, 3) and st.gaussians(0).sh.shape == (4, 1, 3)
    gr = st.grads(g1)
    assert gr["sh_rest"].shape == (4, 15, 3) and np.all(gr["sh_rest"][:, 3:] == 0)
    np.testing.assert_array_equal(gr["sh_rest"][:, :3], g.sh[:, 1:])
    assert list(st.grads(g1, fields=("means",))) == ["means"]


def test_reset_moments_and_checkpoint_roundtrip(rng, tmp_path):
    st = _tagged_state(rng)
    reset_moments(st, "opacity_logits", rows=np.array([1, 3]))
    assert np.all(st.adam.exp_avg["opacity_logits"][[1, 3]] == 0)
    assert np.all(st.adam.exp_avg["opacity_logits"][[0, 2]] != 0)
    st.iteration = 42
    np.savez(tmp_path / "ck.npz", **st.to_arrays())
    st2 = TrainState.from_arrays(np.load(tmp_path / "ck.npz"))
    assert st2.iteration == 42 and st2.adam.step == st.adam.step
    for k in st.params:
        np.testing.assert_array_equal(st2.params[k], st.params[k])
        np.testing.assert_array_equal(st2.adam.exp_avg_sq[k], st.adam.exp_avg_sq[k])
    np.testing.assert_array_equal(st2.stats["denom"], st.stats["denom"])


def test_index_op_errors(rng):
    st = _tagged_state(rng)
    with pytest.raises(ValueError, match="mask"):
        apply_index_op(st, keep=np.ones(3, bool))
    with pytest.raises(IndexError):
        apply_index_op(st, duplicate=np.array([6]))
    with pytest.raises(ValueError, match="missing"):
        apply_index_op(st, append={"means": np.zeros((1, 3))})


@pytest.mark.parametrize("seed", range(5))
def test_then_keep_is_a_second_index_op(seed):
    """apply_index_op(keep, duplicate, append, then_keep=m) leaves every param, moment and stat as
    apply_index_op(keep, duplicate, append) followed by apply_index_op(keep=m) (densify_and_prune's
    growth and prune in one pass), byte for byte, including clones and children that are pruned."""
    import copy

    rng = np.random.default_rng(seed)
    n = 40
    st = _tagged_state(rng, n)
    for k in st.params:  # distinct values per row and column
        st.params[k][...] += rng.normal(size=st.params[k].shape).astype(np.float32)
    keep = rng.uniform(size=n) < 0.7
    dup = rng.integers(0, n, rng.integers(0, 6))
    n_app = int(rng.integers(0, 5))
    append = {k: rng.normal(size=(n_app,) + v.shape[1:]).astype(np.float32) for k, v in st.params.items()} if n_app else None
    m = rng.uniform(size=int(keep.sum()) + len(dup) + n_app) < 0.6
    a, b = copy.deepcopy(st), copy.deepcopy(st)
    apply_index_op(a, keep=keep, duplicate=dup, append=append)
    apply_index_op(a, keep=m)
    apply_index_op(b, keep=keep, duplicate=dup, append=append, then_keep=m)
    assert len(a) == len(b) == int(m.sum())
    for k in st.params:
        for x, y in ((a.params[k], b.params[k]), (a.adam.exp_avg[k], b.adam.exp_avg[k]),
                     (a.adam.exp_avg_sq[k], b.adam.exp_avg_sq[k])):
            assert x.dtype == y.dtype and x.flags.c_contiguous and y.flags.c_contiguous
            np.testing.assert_array_equal(x, y, err_msg=k)
    for k in st.stats:
        assert a.stats[k].dtype == b.stats[k].dtype
        np.testing.assert_array_equal(a.stats[k], b.stats[k], err_msg=k)
    with pytest.raises(ValueError, match="then_keep"):
        apply_index_op(copy.deepcopy(st), keep=keep, then_keep=np.ones(n + 1, bool))


def test_apply_index_op_refuses_appended_rows_of_the_wrong_shape():
    """A wrong row shape in `append` is refused by name before any array is replaced."""
    st = _tagged_state(np.random.default_rng(4), 4)
    before = {k: v.copy() for k, v in st.params.items()}
    app = {k: np.zeros((1,) + v.shape[1:], np.float32) for k, v in st.params.items()}
    app["quats"] = np.zeros((1, 3), np.float32)
    with pytest.raises(ValueError, match=r"fresh\['quats'\]: rows of shape"):
        apply_index_op(st, append=app)
    assert all(np.array_equal(st.params[k], before[k]) for k in before)
