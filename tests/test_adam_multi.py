"""kernels/adam.cl adam_step_multi: the device trainer's Adam step of every group of an `adam_step`
call in one launch (DeviceTrainer.adam_multi, the default on GPUs) against one launch per group
(adam_multi False: adam_step_flat / the strided adam_step), bit for bit: parameters and both
moments after several steps with per-group lrs changing between steps, for several group subsets
(all six; means only; opacity_logits only; the SH groups with one and with several active
coefficients, i.e. flat and strided views of the one "sh" gradient buffer; groups with zero
elements); the step counts; and the launches per call (1, or 0 when every group is empty)."""
from __future__ import annotations

import numpy as np
import pytest

from reings.backends import get_backend
from reings.backends.opencl.harness import ClCalls
from reings.optim import Adam
from reings.state import PARAM_NAMES, TrainState

from test_adam_kernel import _grad_buffers, _state, _trainer

pytest.importorskip("pyopencl")

_LRS = {"means": 0.016, "quats": 0.001, "log_scales": 0.005, "opacity_logits": 0.05, "sh_dc": 0.0025,
        "sh_rest": 0.000125}


def _bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def _run(device, st0, groups_seq, sh_k, multi, seed, steps=4, split=None, fp64=True, flat_views=None,
         loads_first=None):
    """Step a trainer on a copy of st0 `steps` times per entry of groups_seq; returns (state after,
    step counts, launches per adam_step call). split: None (the trainer's choice) or the
    ADAM_MULTI_SPLIT build of adam_step_multi; fp64 False: the ADAM_FP64=0 builds (float
    inv_sqrt_bc2, as on devices without cl_khr_fp64); loads_first: None (the trainer's choice) or the
    ADAM_LOADS_FIRST build of the three kernels."""
    rng = np.random.default_rng(seed)  # the same gradients and lrs for both variants
    st = TrainState.from_arrays(st0.to_arrays())
    n = len(st)
    t = _trainer(device, st, "kernel")
    t.adam_multi = multi
    if flat_views is not None:
        t.adam_flat_views = flat_views
    if not fp64:
        t.fp64 = False
    if split is not None or not fp64 or loads_first is not None:
        defs = dict(t._adam_defs, ADAM_FP64=int(t.fp64))
        if split is not None:
            defs["ADAM_MULTI_SPLIT"] = split
        if loads_first is not None:
            defs["ADAM_LOADS_FIRST"] = loads_first
        t.k_adam = t.b.kernel("adam.cl", "adam_step", **defs)
        t.k_adam_flat = t.b.kernel("adam.cl", "adam_step_flat", **defs)
        t.k_adam_multi = t.b.kernel("adam.cl", "adam_step_multi", **defs)
    opt = Adam(st.params, dict(_LRS), state=st.adam)
    launches = []
    for step in range(steps):
        for groups in groups_seq:
            for k in opt.lr:  # a schedule: every group's lr changes between calls
                opt.lr[k] = _LRS[k] * float(10.0 ** rng.uniform(-1, 1))
            scale = 10.0 ** rng.uniform(-6, 1)
            g = {"means": rng.normal(size=(n, 3)), "quats": rng.normal(size=(n, 4)),
                 "log_scales": rng.normal(size=(n, 3)), "opacity_logits": rng.normal(size=n),
                 "sh": rng.normal(size=(n, sh_k, 3))}
            g = {k: (v * scale).astype(np.float32) for k, v in g.items()}
            if n:
                g["means"][::7] = 0.0
                bufs = _grad_buffers(t, g, sh_k)
            else:
                bufs = {f: t.mem.get("gauss", "test_g_" + f, 1, 64) for f in g}
                bufs["sh_k"] = sh_k
            with ClCalls() as cc:
                t.adam_step(opt, bufs, groups)
            launches.append(cc.n["launches"])
    t.download(st)
    return st, dict(opt.state.step), launches


def _assert_same(a, b, what):
    for k in PARAM_NAMES:
        for x, y, w in ((a.params[k], b.params[k], "param"), (a.adam.exp_avg[k], b.adam.exp_avg[k], "m"),
                        (a.adam.exp_avg_sq[k], b.adam.exp_avg_sq[k], "v")):
            assert x.shape == y.shape, (what, k, w)
            np.testing.assert_array_equal(_bits(x), _bits(y), err_msg=f"{what}: {k} {w}")


ALL = tuple(PARAM_NAMES)
CASES = {
    # name: (n, kmax, sh_k, [groups per call])
    "all_six_sh4": (257, 16, 4, [ALL]),
    "all_six_full_sh": (300, 16, 16, [ALL]),
    "all_six_kmax4": (257, 4, 2, [ALL]),  # sh_rest 9 columns, sh_dc 4 rows per line
    "means_only": (257, 16, 4, [("means",)]),
    "opacity_only": (1000, 4, 4, [("opacity_logits",)]),
    "sh_k1": (257, 16, 1, [("sh_dc", "sh_rest")]),  # sh_dc flat, sh_rest all-zero gradient
    "sh_k9": (257, 16, 9, [("sh_rest", "sh_dc")]),  # both strided views of one buffer
    "mixed_calls": (301, 9, 4, [("means",), ("means", "sh_dc"), ("opacity_logits",), ALL]),
    "sh_rest_empty": (200, 1, 1, [ALL]),  # kmax 1: sh_rest has zero elements
    "n_zero": (0, 4, 1, [ALL, ("means",)]),  # every group empty
}


@pytest.mark.parametrize("flat_views", [False, True])
@pytest.mark.parametrize("case", list(CASES))
def test_adam_multi_matches_per_group_launches(device, case, flat_views):
    """flat_views: the strided SH gradient views stepped in lines of rows (CPUs) or flat, one division per
    element (GPUs): both against one launch per group."""
    _check_case(device, case, None, flat_views=flat_views)


@pytest.mark.parametrize("build", ["nosplit", "split", "fp32"])
@pytest.mark.parametrize("case", ["all_six_full_sh", "all_six_kmax4", "mixed_calls"])
def test_adam_multi_builds(device, case, build):
    """Both builds of adam_step_multi (ADAM_MULTI_SPLIT: the GPUs' without the slot barrier, the CPUs'
    with it), whichever the device would get; and the ADAM_FP64=0 builds of all three kernels."""
    _check_case(device, case, {"nosplit": 0, "split": 1, "fp32": None}[build], build != "fp32")


@pytest.mark.parametrize("wg", [32, 128])
@pytest.mark.parametrize("case", ["all_six_full_sh", "mixed_calls"])
def test_adam_multi_work_group_sizes(device, case, wg):
    """The backend's work-group size sets the lines per work-group (ly = wg // lx): GPUs run 128, PoCL
    256; the same bits at other sizes."""
    be = get_backend(device)
    old = be.wg
    be.wg = wg
    try:
        _check_case(device, case, None)
    finally:
        be.wg = old


def _check_case(device, case, split, fp64=True, flat_views=None):
    n, kmax, sh_k, seq = CASES[case]
    st0 = _state(np.random.default_rng(1), n, kmax)
    got, steps_got, launches = _run(device, st0, seq, sh_k, True, seed=2, split=split, fp64=fp64, flat_views=flat_views)
    ref, steps_ref, launches_ref = _run(device, st0, seq, sh_k, False, seed=2, fp64=fp64)
    _assert_same(got, ref, case)
    assert steps_got == steps_ref
    # each call advanced every named group's count, empty groups included
    want = {k: 0 for k in PARAM_NAMES}
    for groups in seq:
        for k in groups:
            want[k] += 4
    assert steps_got == want
    cols = {"means": 3, "quats": 4, "log_scales": 3, "opacity_logits": 1, "sh_dc": 3, "sh_rest": 3 * (kmax - 1)}
    per_call = [int(any(n * cols[k] for k in g)) for g in seq] * 4
    per_call_ref = [sum(1 for k in g if n * cols[k]) for g in seq] * 4
    assert launches == per_call, launches  # one launch per adam_step call (none when all groups are empty)
    assert launches_ref == per_call_ref
    for k in PARAM_NAMES:  # the stepped groups with a gradient moved
        if n * cols[k] and any(k in g for g in seq) and not (k == "sh_rest" and sh_k == 1):
            assert not np.array_equal(got.params[k], st0.params[k]), k
    if n and kmax > sh_k:  # inactive SH coefficients: zero gradient, values put, moments zero
        np.testing.assert_array_equal(got.params["sh_rest"][:, sh_k - 1:], st0.params["sh_rest"][:, sh_k - 1:])
        assert not np.any(got.adam.exp_avg["sh_rest"][:, sh_k - 1:])


def test_adam_multi_repeated_group(device):
    """A group named twice in one call is stepped twice, in order (a second launch)."""
    st0 = _state(np.random.default_rng(3), 123, 4)
    seq = [("means", "sh_dc", "means", "quats")]
    got, steps, launches = _run(device, st0, seq, 4, True, seed=5, steps=2)
    ref, steps_ref, _ = _run(device, st0, seq, 4, False, seed=5, steps=2)
    _assert_same(got, ref, "repeated group")
    assert steps == steps_ref and steps["means"] == 4
    assert launches == [2, 2]


def test_adam_multi_side_effects(device):
    """adam_step_multi, besides the launch: means steps bump the geometry version (other groups do not), the
    profile gets one "adam" event per launch, an unknown group raises after the groups before it
    were stepped."""
    st = _state(np.random.default_rng(4), 64, 4)
    t = _trainer(device, st, "kernel")
    t.adam_multi = True  # the default on GPUs only (CPU devices: one launch per group)
    t.profile = {}
    opt = Adam(st.params, dict(_LRS), state=st.adam)
    rng = np.random.default_rng(6)
    g = {"means": rng.normal(size=(64, 3)).astype(np.float32), "quats": rng.normal(size=(64, 4)).astype(np.float32),
         "log_scales": rng.normal(size=(64, 3)).astype(np.float32),
         "opacity_logits": rng.normal(size=64).astype(np.float32), "sh": rng.normal(size=(64, 4, 3)).astype(np.float32)}
    bufs = _grad_buffers(t, g, 4)
    geo = t.geometry
    t._events = []
    t.adam_step(opt, bufs, ("opacity_logits", "quats", "sh_rest"))
    assert t.geometry == geo
    assert [s for s, _ in t._events] == ["adam"]
    t.adam_step(opt, bufs, ("sh_dc", "means"))
    assert t.geometry != geo
    assert [s for s, _ in t._events] == ["adam", "adam"]
    t.finish()
    assert t.profile["device_ms"]["adam"] >= 0
    before = t.read_params(["quats"])["quats"]
    with pytest.raises(KeyError, match="nope"):
        t.adam_step(opt, bufs, ("quats", "nope"))
    assert opt.state.step["quats"] == 2
    assert not np.array_equal(t.read_params(["quats"])["quats"], before)


_MULTI_OCLGRIND = """
import numpy as np
import test_adam_multi as T
from test_adam_kernel import _state
for n, kmax, sh_k in ((37, 16, 4), (53, 4, 1)):
    st0 = _state(np.random.default_rng(7), n, kmax)
    seq = [T.ALL, ("means", "sh_dc")]
    ref = T._run("oclgrind", st0, seq, sh_k, False, seed=8, steps=1)[0]
    for split, flat_views, first in ((0, False, 0), (1, False, 0), (0, True, 0), (0, True, 1), (0, False, 1)):
        got, _, launches = T._run("oclgrind", st0, seq, sh_k, True, seed=8, steps=1, split=split,
                                  flat_views=flat_views, loads_first=first)
        T._assert_same(got, ref, f"oclgrind n={n} kmax={kmax} split={split} flat_views={flat_views} first={first}")
        assert launches == [1, 1], launches
    # the per-group kernels (adam_step, adam_step_flat) with the loads first
    got = T._run("oclgrind", st0, seq, sh_k, False, seed=8, steps=1, loads_first=1)[0]
    T._assert_same(got, ref, f"oclgrind n={n} kmax={kmax} per group, loads first")
print("ok")
"""


@pytest.mark.oclgrind
def test_adam_multi_oclgrind():
    """adam_step_multi (both builds: with and without the slot barrier; the GPUs' ADAM_LOADS_FIRST build,
    which PoCL 3.0 cannot run) under Oclgrind's checks (out-of-bounds accesses, races, barrier
    divergence), against the per-group kernels, and those with the loads first."""
    from oclgrind_util import check_script

    check_script(_MULTI_OCLGRIND)


def test_adam_multi_default_follows_the_device(device):
    """One adam_step_multi launch per call on GPUs; one launch per group on CPU devices (PoCL runs the
    multi kernel's 2-D work-groups slower than the per-group kernels: docs/perf_notes.md §29)."""
    st = _state(np.random.default_rng(4), 16, 1)
    t = _trainer(device, st, "kernel")
    assert t.adam_multi == (not t.b.cpu)
