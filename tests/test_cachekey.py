"""Cache keys survive last-bit float differences between machines, and still see real changes."""
import hashlib

import numpy as np

from reings.data.cachekey import hash_image, hash_rounded


def _key(fn, a, *args):
    h = hashlib.sha256()
    fn(h, a, *args)
    return h.hexdigest()


def test_rounded_ignores_float_noise_but_not_changes():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(4, 4)) * 3
    noisy = m * (1 + 1e-15)  # a few ulps, as another numpy build's matmul may give
    assert not np.array_equal(m, noisy)
    assert _key(hash_rounded, m) == _key(hash_rounded, noisy)
    moved = m.copy()
    moved[0, 3] += 1e-4
    assert _key(hash_rounded, m) != _key(hash_rounded, moved)
    assert _key(hash_rounded, np.array([0.0])) == _key(hash_rounded, np.array([-0.0]))


def test_image_8bit_and_float():
    rng = np.random.default_rng(1)
    u8 = rng.integers(0, 256, size=(5, 7, 3))
    a = (u8 / 255.0).astype(np.float32)
    b = (u8.astype(np.float64) / 255.0).astype(np.float32)  # the same pixels through another path
    assert _key(hash_image, a) == _key(hash_image, b)
    c = a.copy()
    c[2, 3, 1] = (u8[2, 3, 1] ^ 1) / 255.0  # one 8-bit level on one pixel
    assert _key(hash_image, a) != _key(hash_image, c)
    f = a + np.float32(0.3 / 255.0)  # not 8-bit data: hashed as float32, still sensitive
    f2 = f.copy()
    f2[0, 0, 0] = np.nextafter(f2[0, 0, 0], np.float32(2))
    assert _key(hash_image, f) != _key(hash_image, f2)
