"""reings.seeding against numpy's SeedSequence / PCG64 / Generator.random, bit for bit, and the fit's
per-iteration draws (train.drop_at, train.warp_baseline) with and without IterationDraws."""
import numpy as np
import pytest

from reings.seeding import IterationDraws, pcg64_randoms, state_words_block
from reings.train import drop_at, warp_baseline

RNG = np.random.default_rng(20261127)
# (seed, stream, first iteration): seeds small and up to 2**32 - 1, iterations up to 2**32 - 1
CASES = [(int(RNG.integers(0, 2**32)) if i % 3 else int(RNG.integers(0, 10)), int(RNG.integers(0, 5)),
          int(RNG.integers(0, 100_000))) for i in range(60)] + [(0, 0, 0), (2**32 - 1, 2**32 - 1, 2**32 - 9)]


@pytest.mark.parametrize("seed,stream,first", CASES)
def test_state_words_and_pcg64_match_numpy(seed, stream, first):
    blk = state_words_block((seed, stream), first, 8, 8)
    for j in range(8):
        ss = np.random.SeedSequence([seed, stream, first + j])
        np.testing.assert_array_equal(blk[j], ss.generate_state(8, np.uint32))
        g = np.random.default_rng([seed, stream, first + j])
        assert pcg64_randoms(blk[j], 3) == [g.random() for _ in range(3)]
        assert pcg64_randoms(blk[j].tolist(), 1) == pcg64_randoms(blk[j], 1)


@pytest.mark.parametrize("prefix", [(), (7,), (3, 1, 4)])
def test_state_words_block_other_entropy_lengths(prefix):
    blk = state_words_block(prefix, 5, 3, 2)
    for j in range(3):
        np.testing.assert_array_equal(blk[j], np.random.SeedSequence([*prefix, 5 + j]).generate_state(2, np.uint32))


def test_state_words_block_refuses_what_it_cannot_coerce():
    with pytest.raises(ValueError):
        state_words_block((2**32, 1), 1, 4, 1)  # two entropy words for the seed
    with pytest.raises(ValueError):
        state_words_block((0, 1), 2**32, 1, 1)
    with pytest.raises(ValueError):
        state_words_block((0, 1, 2, 3), 1, 1, 1)  # five entries: more than the pool
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
