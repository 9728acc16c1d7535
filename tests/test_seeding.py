"""reings.seeding against numpy's SeedSequence / PCG64 / Generator.random, bit for bit, and the fit's
per-iteration draws (train.drop_at, train.warp_baseline) with and without IterationDraws."""
import numpy as np
import pytest

from reings.seeding import (IterationDraws, pcg64_randoms, pcg64_randoms_from_state, seed_pool, state_words,
                            state_words_block, uint32_key)
from reings.train import drop_at, warp_baseline

RNG = np.random.default_rng(20261127)
CASES = [[int(RNG.integers(0, 2**40)) if i % 3 else int(RNG.integers(0, 10)), int(RNG.integers(0, 5)),
          int(RNG.integers(0, 100_000))] for i in range(300)]


@pytest.mark.parametrize("entropy", CASES[:300] + [0, 17, 2**70, [1, 2, 3, 4, 5, 6], [2**32 - 1, 2**32, 0]])
def test_seed_sequence_and_pcg64_match_numpy(entropy):
    ss = np.random.SeedSequence(entropy)
    assert seed_pool(entropy) == [int(x) for x in ss.pool]
    assert state_words(seed_pool(entropy), 8) == [int(x) for x in ss.generate_state(8, np.uint32)]
    assert uint32_key(entropy) == int(ss.generate_state(1, np.uint32)[0])
    g = np.random.default_rng(entropy)
    assert pcg64_randoms(entropy, 4) == [g.random() for _ in range(4)]


@pytest.mark.parametrize("seed,stream", [(0, 1), (0, 2), (3, 1), (2**32 - 1, 2), (123456789, 7)])
def test_state_words_block_matches_numpy(seed, stream):
    first, count = 1000, 1100  # crosses no block rule: a plain range
    blk = state_words_block((seed, stream), first, count, 8)
    for it in (first, first + 1, first + 517, first + count - 1):
        want = np.random.SeedSequence([seed, stream, it]).generate_state(8, np.uint32)
        np.testing.assert_array_equal(blk[it - first], want)
        g = np.random.default_rng([seed, stream, it])
        assert pcg64_randoms_from_state(blk[it - first].tolist(), 2) == [g.random(), g.random()]


def test_state_words_block_refuses_what_it_cannot_coerce():
    with pytest.raises(ValueError):
        state_words_block((2**32, 1), 1, 4, 1)  # two entropy words for the seed
    with pytest.raises(ValueError):
        state_words_block((0, 1), 2**32, 1, 1)
    with pytest.raises(ValueError):
        IterationDraws(-1)
    assert not IterationDraws.supports(2**32) and not IterationDraws.supports(np.int64(3))


@pytest.mark.parametrize("seed", [0, 1, 5, 4_000_000_000])
def test_fit_draws_are_numpys(seed):
    """drop_at / warp_baseline with the fit's IterationDraws give the numpy form's values, across block edges."""
    d = IterationDraws(seed)
    its = [1, 2, 3, 1023, 1024, 1025, 2048, 2049, 5999, 6000, 15000] + [int(x) for x in RNG.integers(1, 30000, 40)]
    for it in its:
        a, b = drop_at(0.2, seed, it, 6000), drop_at(0.2, seed, it, 6000, d)
        assert a.args() == b.args(), it
        assert warp_baseline(seed, it, 0.4) == warp_baseline(seed, it, 0.4, d), it
        assert warp_baseline(seed, it, 0.05) == warp_baseline(seed, it, 0.05, d), it
    assert drop_at(0.0, seed, 5, 10, d) is None


def test_fit_draws_of_another_seed_are_refused():
    d = IterationDraws(3)
    with pytest.raises(ValueError):
        drop_at(0.2, 4, 10, 100, d)
    with pytest.raises(ValueError):
        warp_baseline(4, 10, 0.4, d)
