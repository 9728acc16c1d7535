"""The checkpoints' time floor (`OutputConfig.checkpoint_seconds`, `fit(checkpoint_seconds=)`, issue 15):
a checkpoint is written at a multiple of `checkpoint_every` only when at least that many seconds
have passed since the fit's last one (or its start or resume), always after the fit's last
iteration; 0 keeps the old rule (every multiple). The clock is injected (`_Bookkeeping(clock=)`),
never slept on. Which iterations write one changes nothing of the fit: the state is the same bit for
bit, and a fit resumed from a checkpoint the floor let through equals the uninterrupted one."""
from __future__ import annotations

import os
from types import SimpleNamespace

import numpy as np
import pytest

import reings.train as T
from cases import assert_same_state, dngaussian_fit_case, fit_case, interrupt_and_resume
from reings.config import OutputConfig, RunConfig


def _written(monkeypatch, iterations: int, every: int, seconds: float, clock_at) -> list[int]:
    """The iterations after which `_Bookkeeping.end` writes the checkpoint, with the clock reading
    clock_at(it) (seconds) at iteration `it` (0 before the first)."""
    saved, now = [], {"it": 0}
    monkeypatch.setattr(T, "_save_checkpoint", lambda path, st, rng, h, extra: saved.append(now["it"]))
    state = type("S", (), {"__len__": lambda self: 1})()
    book = T._Bookkeeping(SimpleNamespace(iterations=iterations), state, T.History(), None, 0.0, False, "t",
                          "ck.npz", every, None, 0, 10**9, checkpoint_seconds=seconds,
                          clock=lambda: clock_at(now["it"]))
    for it in range(1, iterations + 1):
        now["it"] = it
        book.end(it, 0, 0.0, 0.0)
    assert book.checkpoints == len(saved)
    return saved


def test_the_floor_skips_checkpoints_until_enough_seconds_passed(monkeypatch):
    # 3 s an iteration, every 2 iterations, a 10 s floor: written at 4 (12 s), 8 (24 s), 12, 16; 20 ends the fit
    assert _written(monkeypatch, 20, 2, 10.0, lambda it: 3.0 * it) == [4, 8, 12, 16, 20]
    # a slow fit (100 s an iteration): the floor never holds one back, every multiple as without it
    assert _written(monkeypatch, 9, 2, 60.0, lambda it: 100.0 * it) == [2, 4, 6, 8, 9]
    # the floor counts from the last checkpoint written, not from the last multiple
    assert _written(monkeypatch, 12, 1, 2.5, lambda it: float(it)) == [3, 6, 9, 12]


def test_the_end_of_a_fit_is_always_checkpointed(monkeypatch):
    assert _written(monkeypatch, 7, 2, 1e9, lambda it: 0.01 * it) == [7]
    assert _written(monkeypatch, 8, 4, 1e9, lambda it: 0.01 * it) == [8]
    assert _written(monkeypatch, 1, 250, 1e9, lambda it: 0.0) == [1]


def test_zero_seconds_is_every_multiple(monkeypatch):
    assert _written(monkeypatch, 10, 3, 0.0, lambda it: 0.0) == [3, 6, 9, 10]  # a clock that never moves
    assert _written(monkeypatch, 10, 3, 0.0, lambda it: 1e-3 * it) == [3, 6, 9, 10]


def test_no_path_no_checkpoint(monkeypatch):
    saved = []
    monkeypatch.setattr(T, "_save_checkpoint", lambda *a: saved.append(a))
    state = type("S", (), {"__len__": lambda self: 1})()
    book = T._Bookkeeping(SimpleNamespace(iterations=4), state, T.History(), None, 0.0, False, "t", None, 1, None, 0,
                          10**9, checkpoint_seconds=0.0)
    for it in range(1, 5):
        book.end(it, 0, 0.0, 0.0)
    assert saved == [] and book.checkpoints == 0


def test_the_option_and_its_default():
    assert OutputConfig().checkpoint_seconds == 60.0 and OutputConfig().checkpoint_every == 250
    assert RunConfig(output=OutputConfig(checkpoint_seconds=0)).output.checkpoint_seconds == 0.0
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="checkpoint_seconds"):
            OutputConfig(checkpoint_seconds=bad)


@pytest.fixture(scope="module")
def case():
    # test_device_fit's case: densification at 10 and 20, the SH degree raised at 4
    return dngaussian_fit_case(n_views=3, width=64, height=48, n_points=300, sh_degree=1, iterations=23,
                               soft_depth_from=3, densify_until=25)


def test_a_fit_with_the_floor_resumes_bit_identically(device, case, tmp_path, monkeypatch):
    """A clock of 10 s an iteration, checkpoints every 2 iterations, a 25 s floor: written at 4, 8,
    12, 16, 20 and 23 (the end); interrupted at iteration 15 (last checkpoint at 12) and resumed
    (the floor counts from the resume): the uninterrupted fit's state and losses, bit for bit, as a
    fit that checkpoints at every iteration gives."""
    saved = []
    real_save = T._save_checkpoint

    def save(path, st, rng, h, extra):
        saved.append(st.iteration)
        real_save(path, st, rng, h, extra)

    class Book(T._Bookkeeping):  # the clock: 10 s per completed iteration of the fit's state
        def __init__(self, cfg, state, *a, **k):
            super().__init__(cfg, state, *a, **{**k, "clock": lambda: 10.0 * state.iteration})

    monkeypatch.setattr(T, "_save_checkpoint", save)
    monkeypatch.setattr(T, "_Bookkeeping", Book)
    ref = fit_case(case, device, engine="device")
    every = fit_case(case, device, engine="device", checkpoint=os.path.join(tmp_path, "every.npz"),
                     checkpoint_every=1, checkpoint_seconds=0)
    assert saved == list(range(1, 24))
    assert_same_state(ref.state, every.state, True, "checkpoint at every iteration vs none")
    saved.clear()
    path = os.path.join(tmp_path, "ck.npz")
    res = interrupt_and_resume(lambda **kw: fit_case(case, device, engine="device", checkpoint_seconds=25.0, **kw),
                               path, stop_at=15, every=2)
    assert saved == [4, 8, 12, 16, 20, 23]
    assert_same_state(ref.state, res.state, True, "resumed (floor) vs uninterrupted")
    np.testing.assert_array_equal(res.history.loss, ref.history.loss)
    assert [tuple(x) for x in res.history.densify] == [tuple(x) for x in ref.history.densify]
