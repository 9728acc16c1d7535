"""numpy's SeedSequence and PCG64 for the fit's per-iteration draws, without numpy objects per iteration
(issue 15: host time per step).

The fit draws a few numbers per iteration from generators of their own (`reings.train.drop_at`: DropGaussian's
key, `numpy.random.SeedSequence([seed, 2, it]).generate_state(1, uint32)`; `warp_baseline`: the virtual view's
baseline, two `random()` draws of `numpy.random.default_rng([seed, 1, it])`), so that a resumed fit draws the same.
Building those numpy objects costs ~25-30 us per iteration, a few percent of a GPU step whose time is the host's
(docs/perf_notes.md §18). `IterationDraws` computes the same numbers from the published algorithms:

- SeedSequence (numpy.random.bit_generator: one uint32 word per small entropy entry, a pool of 4 words mixed with
  `hashmix` / `mix`, `generate_state` hashing the pool cyclically), for a block of iterations at once in uint32
  lanes (`state_words_block`);
- PCG64 (O'Neill's PCG XSL RR 128/64, numpy's `PCG64`: state and increment from `generate_state(4, uint64)`,
  the increment forced odd, one step, the state added, one step; each output steps then permutes the state) in
  Python integers, and Generator.random() = (next_uint64 >> 11) * 2**-53 (`pcg64_randoms`).

tests/test_seeding.py checks them against numpy bit for bit.
"""
from __future__ import annotations

import numpy as np

M32 = 0xFFFFFFFF
M64 = (1 << 64) - 1
M128 = (1 << 128) - 1
POOL_SIZE = 4
INIT_A, MULT_A = 0x43B0D7E5, 0x931E8875
INIT_B, MULT_B = 0x8B51F9DD, 0x58F38DED
MIX_MULT_L, MIX_MULT_R = 0xCA01F9DD, 0x4973F715
XSHIFT = np.uint32(16)
PCG_MULT = (2549297995355413924 << 64) + 4865540595714422341  # PCG_DEFAULT_MULTIPLIER_128


def state_words_block(prefix: tuple, first: int, count: int, n_words: int) -> np.ndarray:
    """SeedSequence([*prefix, it]).generate_state(n_words, uint32) for it = first .. first + count - 1 at
    once (uint32 lanes, one per iteration): [count, n_words] uint32. Every prefix entry and every
    iteration must lie in [0, 2**32) (one entropy word each), at most POOL_SIZE entries in all."""
    its = np.arange(first, first + count, dtype=np.uint64)
    if first < 0 or (count and int(its[-1]) > M32) or any(not 0 <= int(p) <= M32 for p in prefix) \
            or len(prefix) + 1 > POOL_SIZE:
        raise ValueError("state_words_block: one uint32 word per entropy entry, at most 4 entries")
    words = [np.full(count, int(p), np.uint32) for p in prefix] + [its.astype(np.uint32)]
    h = INIT_A

    def hashmix(v):
        nonlocal h
        v = v ^ np.uint32(h)
        h = (h * MULT_A) & M32
        v = v * np.uint32(h)
        return v ^ (v >> XSHIFT)

    def mix(x, y):
        r = np.uint32(MIX_MULT_L) * x - np.uint32(MIX_MULT_R) * y
        return r ^ (r >> XSHIFT)

    pool = [hashmix(words[i] if i < len(words) else np.zeros(count, np.uint32)) for i in range(POOL_SIZE)]
    for i_src in range(POOL_SIZE):
        for i_dst in range(POOL_SIZE):
            if i_src != i_dst:
                pool[i_dst] = mix(pool[i_dst], hashmix(pool[i_src]))
    out = np.empty((count, n_words), np.uint32)
    h = INIT_B
    for i in range(n_words):
        v = pool[i % POOL_SIZE] ^ np.uint32(h)
        h = (h * MULT_B) & M32
        v = v * np.uint32(h)
        out[:, i] = v ^ (v >> XSHIFT)
    return out


def pcg64_randoms(w, n: int) -> list[float]:
    """The first n `random()` doubles of numpy.random.default_rng(entropy), from the 8 words `w` of
    SeedSequence(entropy).generate_state(8, uint32) (Python ints or uint32)."""
    w = [int(x) for x in w]
    u64 = [w[2 * i] | (w[2 * i + 1] << 32) for i in range(4)]  # generate_state(4, uint64), little-endian
    initstate = (u64[0] << 64) | u64[1]
    inc = ((((u64[2] << 64) | u64[3]) << 1) | 1) & M128
    state = ((inc + initstate) * PCG_MULT + inc) & M128  # step from 0 (= inc), add the state, step
    out = []
    for _ in range(n):
        state = (state * PCG_MULT + inc) & M128
        x = ((state >> 64) ^ state) & M64
        rot = state >> 122
        x = ((x >> rot) | (x << ((-rot) & 63))) & M64
        out.append((x >> 11) * (1.0 / 9007199254740992.0))
    return out


class IterationDraws:
    """The generate_state words of SeedSequence([seed, stream, it]) for a fit's iterations it >= 1, computed
    BLOCK iterations at a time (`state_words_block`) and kept as Python ints: DropGaussian's key (stream 2,
    `uint32_key`) and the virtual view's baseline draws (stream 1, `randoms`) without building numpy
    generators per iteration. `seed` must lie in [0, 2**32) (`supports`)."""

    BLOCK = 1024
    WORDS = 8  # enough for a PCG64 seed (4 uint64); a uint32 key is the first word

    def __init__(self, seed: int):
        if not self.supports(seed):
            raise ValueError(f"IterationDraws: seed must lie in [0, 2**32), got {seed!r}")
        self.seed = int(seed)
        self._blocks: dict = {}

    @staticmethod
    def supports(seed) -> bool:
        return isinstance(seed, int) and 0 <= seed <= M32

    def words(self, stream: int, it: int) -> list[int]:
        if not 1 <= it <= M32:
            raise ValueError(f"IterationDraws: iteration {it} outside [1, 2**32)")
        b, i = divmod(it - 1, self.BLOCK)
        blk = self._blocks.get((stream, b))
        if blk is None:
            if len(self._blocks) >= 8:
                self._blocks.clear()
            first = b * self.BLOCK + 1
            count = min(self.BLOCK, M32 - first + 1)
            blk = self._blocks[(stream, b)] = state_words_block((self.seed, stream), first, count, self.WORDS).tolist()
        return blk[i]

    def uint32_key(self, stream: int, it: int) -> int:
        """SeedSequence([seed, stream, it]).generate_state(1, uint32)[0]."""
        return self.words(stream, it)[0]

    def randoms(self, stream: int, it: int, n: int) -> list[float]:
        """The first n random() of numpy.random.default_rng([seed, stream, it])."""
        return pcg64_randoms(self.words(stream, it), n)
