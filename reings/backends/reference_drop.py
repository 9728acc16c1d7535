"""DropGaussian's random mask (Park, Ryu, Kim, CVPR 2025, arXiv 2504.00773; docs/method.md §9):
the numpy twin of `DROP_HASH` in kernels/project.cl, and the `Drop` value that carries one
iteration's mask from the training loop to the projection.

During a fit's photometric pass each Gaussian is dropped with rate r_t = gamma * t / T and every
kept one's opacity is multiplied by 1 / (1 - r_t). The mask is counter-based: Gaussian `gid` is
kept iff

    drop_hash(gid, key) >= threshold,        threshold = min(floor(r * 2^32), 2^32 - 1)

with drop_hash murmur3's 32-bit finaliser (fmix32) of gid ^ (key * DROP_KEY_MUL), all in uint32
arithmetic (wrapping mod 2^32). fmix32 is a bijection of uint32, so for any key exactly
2^32 - threshold of the 2^32 gids are kept: a Gaussian is kept with probability 1 - r (to 2^-32).
Nothing is uploaded: the projection kernel recomputes the hash from (gid, key); the same three
numbers here give the same mask, bit for bit (tests/test_drop.py).

Lives in the reference layer so that the engine (reings/train.py, which makes a `Drop` per
iteration) and every backend can import it (docs/architecture.md §1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DROP_KEY_MUL = 0x9E3779B9  # 2^32 / golden ratio: spreads consecutive keys (kernels/project.cl)
DROP_FMIX_MUL1 = 0x85EBCA6B  # murmur3 fmix32 constants (kernels/project.cl)
DROP_FMIX_MUL2 = 0xC2B2AE35
_U32 = np.uint32


def drop_hash(gid, key: int) -> np.ndarray:
    """murmur3 fmix32 of gid ^ (key * DROP_KEY_MUL), uint32 arithmetic; gid an int array (values
    taken mod 2^32), key an int in [0, 2^32). The twin of DROP_HASH (kernels/project.cl)."""
    k = _U32((int(key) * DROP_KEY_MUL) & 0xFFFFFFFF)
    h = np.asarray(gid).astype(np.uint64).astype(_U32) ^ k  # (unsigned wrap of any int gid)
    with np.errstate(over="ignore"):
        h ^= h >> _U32(16)
        h *= _U32(DROP_FMIX_MUL1)
        h ^= h >> _U32(13)
        h *= _U32(DROP_FMIX_MUL2)
        h ^= h >> _U32(16)
    return h


def drop_threshold(rate: float) -> int:
    """The kernel's keep threshold of drop rate `rate` in [0, 1]: min(floor(rate * 2^32), 2^32 - 1)."""
    r = float(rate)
    if not 0.0 <= r <= 1.0:  # also NaN
        raise ValueError(f"drop rate must lie in [0, 1], got {rate!r}")
    return min(int(np.floor(r * 2.0**32)), 2**32 - 1)


@dataclass(frozen=True)
class Drop:
    """One render's DropGaussian mask and opacity compensation (None where a render drops
    nothing). key: uint32 of the mask; threshold: keep gid iff drop_hash(gid, key) >= threshold
    (0 keeps all); scale: the kept Gaussians' opacity factor, float32 of 1 / (1 - rate). Build
    with `Drop.at_rate`."""

    key: int
    threshold: int
    scale: float

    @classmethod
    def at_rate(cls, rate: float, key: int) -> "Drop":
        """The mask of drop rate `rate` in [0, 1) with `key` (an int in [0, 2^32))."""
        r = float(rate)
        if not 0.0 <= r < 1.0:  # also NaN
            raise ValueError(f"drop rate must lie in [0, 1), got {rate!r}")
        if not 0 <= int(key) < 2**32:
            raise ValueError(f"drop key must be a uint32, got {key!r}")
        return cls(int(key), drop_threshold(r), float(np.float32(1.0 / (1.0 - r))))

    def kept(self, n: int) -> np.ndarray:
        """[n] bool: the Gaussians gid = 0..n-1 this mask keeps."""
        if self.threshold == 0:
            return np.ones(n, bool)
        return drop_hash(np.arange(n, dtype=np.int64), self.key) >= _U32(self.threshold)

    def args(self) -> tuple[np.uint32, np.uint32, np.float32]:
        """(key, threshold, scale) as the kernels' scalar argument types."""
        return _U32(self.key), _U32(self.threshold), np.float32(self.scale)


NO_DROP_ARGS = (_U32(0), _U32(0), np.float32(1.0))  # the kernels' arguments of "no drop"


def drop_args(drop: Drop | None) -> tuple:
    """The project kernels' (key, threshold, scale) arguments of `drop` (None: keep all, scale 1)."""
    return NO_DROP_ARGS if drop is None else drop.args()
