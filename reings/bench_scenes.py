"""The docs/perf_notes.md §1.7 benchmark scenes A/B/C, seeded and reproducible with numpy alone.

    camera: identity world->camera; fx = fy = 420, cx = 252, cy = 189; 504x378; near 0.01
    z ~ U(2, 8); x = U(-1.15, 1.15)*(W/2/fx)*z; y = U(-1.15, 1.15)*(H/2/fy)*z
    log-scales ~ N(ln s_med, 0.5) per axis; s_med = 0.02 (A, C) or 0.05 (B); N = 100k (A, B), 300k (C)
    quats ~ N(0, 1)^4, normalised; opacity logits ~ N(0.5, 1.5)
    SH degree 0: DC ~ U(-1, 1.5); degree 3: DC as above, higher bands ~ N(0, 0.1)

Draw order (fixes the exact arrays): one `numpy.random.default_rng(seed)` (seed 0), drawing
z, x-unit, y-unit, log-scales, quats, logits, DC, then (degree 3 only) the higher bands.
"""
from __future__ import annotations

import numpy as np

from .types import Camera, Gaussians

WIDTH, HEIGHT = 504, 378
FX = FY = 420.0
CX, CY = 252.0, 189.0
SCENES = {"A": (100_000, 0.02), "B": (100_000, 0.05), "C": (300_000, 0.02)}


def perf_camera() -> Camera:
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]], dtype=np.float64)
    return Camera(K, np.eye(4), WIDTH, HEIGHT)


def perf_scene(name: str, sh_degree: int | None = None, seed: int = 0, n: int | None = None):
    """Scene `name` in {"A", "B", "C"}, optionally suffixed "-sh3"/"_sh3"/"-sh0" (or pass sh_degree;
    default 0). `n` overrides the Gaussian count (smaller test versions). Returns (Gaussians, Camera)."""
    key = name.upper().replace("_", "-")
    base, _, sh = key.partition("-")
    if base not in SCENES:
        raise ValueError(f"perf_scene: unknown scene {name!r}; valid: A, B, C (optionally -sh0/-sh3)")
    if sh:
        if sh not in ("SH0", "SH3"):
            raise ValueError(f"perf_scene: unknown SH suffix in {name!r}")
        deg = int(sh[2])
        if sh_degree is not None and sh_degree != deg:
            raise ValueError(f"perf_scene: {name!r} conflicts with sh_degree={sh_degree}")
        sh_degree = deg
    sh_degree = 0 if sh_degree is None else int(sh_degree)
    count, s_med = SCENES[base]
    count = count if n is None else int(n)
    rng = np.random.default_rng(seed)
    z = rng.uniform(2.0, 8.0, count)
    x = rng.uniform(-1.15, 1.15, count) * (WIDTH / 2 / FX) * z
    y = rng.uniform(-1.15, 1.15, count) * (HEIGHT / 2 / FY) * z
    log_scales = rng.normal(np.log(s_med), 0.5, (count, 3))
    q = rng.normal(0.0, 1.0, (count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    logits = rng.normal(0.5, 1.5, count)
    k = (sh_degree + 1) ** 2
    sh = np.zeros((count, k, 3))
    sh[:, 0, :] = rng.uniform(-1.0, 1.5, (count, 3))
    if k > 1:
        sh[:, 1:, :] = rng.normal(0.0, 0.1, (count, k - 1, 3))
    g = Gaussians(np.stack([x, y, z], 1), q, log_scales, logits, sh)
    return g, perf_camera()
