"""Cache keys that survive a move between machines.

A cached depth prior or SfM box is reused on another machine (e.g. a GPU host without pycolmap)
only if its key is computed there bit for bit the same. Pixels loaded from 8-bit files are exact
everywhere, but camera matrices derived in float64 can differ in their last bits between numpy
builds (SIMD paths of matmul and friends), and a raw `tobytes()` hash then misses. So: images are
hashed as 8-bit values when they are 8-bit data (else as float32), and camera matrices, bounds and
points rounded to `decimals` places (1e-6: far below any change that alters a result, far above
float64 noise).
"""
from __future__ import annotations

import numpy as np


def hash_array(h, a) -> None:
    a = np.ascontiguousarray(a)
    h.update(str((a.dtype.str, a.shape)).encode())
    h.update(a.tobytes())


def hash_image(h, im) -> None:
    """8-bit images (every value a multiple of 1/255 within float32 rounding) as uint8, others as
    float32."""
    a = np.asarray(im, np.float32)
    q = np.rint(a * 255.0)
    if a.size and np.all(np.abs(a * 255.0 - q) < 1e-3) and q.min() >= 0 and q.max() <= 255:
        hash_array(h, q.astype(np.uint8))
    else:
        hash_array(h, a)


def hash_rounded(h, a, decimals: int = 6) -> None:
    """A float array rounded to `decimals` places (negative zero folded to zero)."""
    r = np.round(np.asarray(a, np.float64), decimals) + 0.0
    hash_array(h, r)


def scene_digest(scene) -> str:
    """sha256 of a scene's images, cameras and names (an in-memory scene's identity in a run's
    resume settings)."""
    import hashlib

    h = hashlib.sha256()
    for name, im, cam in zip(scene.names, scene.images, scene.cameras):
        h.update(str(name).encode())
        hash_image(h, im)
        hash_rounded(h, cam.K)
        hash_rounded(h, cam.viewmat)
    return h.hexdigest()
