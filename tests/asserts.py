"""Comparison helpers with useful failure messages (STYLE.md §3.7).

assert_close:               per element |a-e| <= atol + rtol*|e|; reports count, worst index, first pairs
assert_grad_close:          cosine, relative L2 and signed bias of a whole gradient field
assert_close_outside_band:  tight outside a discontinuity band, a flip budget inside it
"""
from __future__ import annotations

import numpy as np


def _pairs(a, e, idx, k=5):
    out = []
    for flat in idx[:k]:
        i = np.unravel_index(flat, e.shape) if e.ndim else ()
        out.append(f"  {tuple(int(x) for x in i)}: actual={a.flat[flat]!r} expected={e.flat[flat]!r}")
    return "\n".join(out)


def assert_close(actual, expected, atol: float, rtol: float = 0.0, name: str = "value"):
    """Element-wise |actual - expected| <= atol + rtol*|expected|, NaN never equal to anything."""
    a = np.asarray(actual, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    if a.shape != e.shape:
        raise AssertionError(f"{name}: shape {a.shape} != expected {e.shape}")
    if a.size == 0:
        return
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.abs(a - e)
        tol = atol + rtol * np.abs(e)
        bad = ~(err <= tol)  # NaN -> bad
        both_inf = np.isinf(a) & np.isinf(e) & (np.sign(a) == np.sign(e))
        bad &= ~both_inf
    if bad.any():
        idx = np.flatnonzero(bad)
        errf = np.where(bad, np.nan_to_num(err, nan=np.inf), -1.0).ravel()
        worst = int(np.argmax(errf))
        wi = tuple(int(x) for x in np.unravel_index(worst, e.shape))
        raise AssertionError(
            f"{name}: {len(idx)}/{a.size} elements beyond atol={atol:g} rtol={rtol:g}; "
            f"worst at {wi}: actual={a.flat[worst]!r} expected={e.flat[worst]!r} "
            f"err={err.flat[worst]:.3e}\nfirst mismatches:\n{_pairs(a, e, idx)}")


def grad_stats(actual, expected) -> dict:
    """cosine, rel_l2 (= |a-e|/|e|), bias (= mean(a-e)/rms(e)), max_abs_err."""
    a = np.asarray(actual, np.float64).ravel()
    e = np.asarray(expected, np.float64).ravel()
    ne, na = np.linalg.norm(e), np.linalg.norm(a)
    d = a - e
    cos = float(a @ e / (na * ne)) if na > 0 and ne > 0 else (1.0 if na == ne else 0.0)
    rel = float(np.linalg.norm(d) / ne) if ne > 0 else (0.0 if na == 0 else np.inf)
    rms = ne / np.sqrt(max(e.size, 1))
    bias = float(d.mean() / rms) if rms > 0 and e.size else (0.0 if not d.any() else np.inf)
    return dict(cosine=cos, rel_l2=rel, bias=bias, max_abs_err=float(np.abs(d).max()) if d.size else 0.0)


def assert_grad_close(actual, expected, name: str = "grad", min_cosine: float = 0.999,
                      max_rel_l2: float = 1e-3, max_bias: float | None = None):
    """Whole-field gradient agreement: cosine >= min_cosine and relative L2 <= max_rel_l2 (the
    issue's numbers), optionally |signed bias| <= max_bias. An all-zero expected field needs an
    all-zero actual one. Non-finite values always fail."""
    a = np.asarray(actual, np.float64)
    e = np.asarray(expected, np.float64)
    if a.shape != e.shape:
        raise AssertionError(f"{name}: shape {a.shape} != expected {e.shape}")
    if not np.all(np.isfinite(a)):
        raise AssertionError(f"{name}: {np.count_nonzero(~np.isfinite(a))} non-finite values in actual")
    if not np.all(np.isfinite(e)):
        raise AssertionError(f"{name}: {np.count_nonzero(~np.isfinite(e))} non-finite values in expected")
    if a.size == 0:
        return
    st = grad_stats(a, e)
    if not np.any(e):
        if np.any(a):
            raise AssertionError(f"{name}: expected all zeros, actual has max |.| {np.abs(a).max():.3e}")
        return
    msgs = []
    if not st["cosine"] >= min_cosine:
        msgs.append(f"cosine {st['cosine']:.6f} < {min_cosine}")
    if not st["rel_l2"] <= max_rel_l2:
        msgs.append(f"rel L2 {st['rel_l2']:.3e} > {max_rel_l2:g}")
    if max_bias is not None and not abs(st["bias"]) <= max_bias:
        msgs.append(f"signed bias {st['bias']:.3e} beyond ±{max_bias:g}")
    if msgs:
        d = np.abs(a - e).ravel()
        idx = np.argsort(-d)
        raise AssertionError(f"{name}: " + "; ".join(msgs) + f" (max abs err {st['max_abs_err']:.3e})"
                             f"\nlargest differences:\n{_pairs(a, e, idx)}")


def assert_close_outside_band(actual, expected, band_mask, atol: float, max_flip_fraction: float,
                              name: str = "value", rtol: float = 0.0):
    """Tight (atol, rtol) where band_mask is False; inside the band, at most max_flip_fraction of
    ALL elements may differ beyond atol (a discontinuity may flip either way, never NaN)."""
    a = np.asarray(actual, np.float64)
    e = np.asarray(expected, np.float64)
    band = np.broadcast_to(np.asarray(band_mask, bool), e.shape)
    if a.shape != e.shape:
        raise AssertionError(f"{name}: shape {a.shape} != expected {e.shape}")
    if not np.all(np.isfinite(a)):
        raise AssertionError(f"{name}: non-finite values in actual")
    assert_close(np.where(band, e, a), e, atol, rtol, name=f"{name} (outside band)")
    with np.errstate(invalid="ignore"):
        flips = band & ~(np.abs(a - e) <= atol + rtol * np.abs(e))
    nf = int(np.count_nonzero(flips))
    if nf > max_flip_fraction * max(e.size, 1):
        idx = np.flatnonzero(flips)
        raise AssertionError(f"{name}: {nf}/{e.size} elements differ inside the band "
                             f"(budget {max_flip_fraction:g})\n{_pairs(a, e, idx)}")
