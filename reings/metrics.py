"""Image-quality metrics as the few-shot novel-view-synthesis literature computes them.

All functions take images as (H, W, 3) float arrays in [0, 1] (any float dtype; computed in
float64, LPIPS in float32). Values slightly outside [0, 1] are clipped (the compared papers save
renders as 8-bit PNGs, which clips them too); NaN or Inf raise a `ValueError`.

* `psnr` = -10 log10(MSE), MSE over all pixels and channels of one image. With a mask (DTU
  protocol): MSE over the foreground pixels only (all three channels).
* `ssim(kind="gs")` = the 3DGS-family SSIM (Gaussian window 11, sigma 1.5, zero-padded 'same'
  convolution, C1 = 0.01^2, C2 = 0.03^2, mean over the whole map and the channels).
  `ssim(kind="skimage")` = `skimage.metrics.structural_similarity(data_range=1, channel_axis=-1)`
  (7x7 uniform window, sample covariance, symmetric padding, border of 3 cropped), reimplemented
  here so scikit-image is not a runtime dependency (the tests check equality).
* `lpips` = LPIPS v0.1 with the VGG16 backbone, run by onnxruntime from `lpips_vgg.onnx`.
  convention="3dgs" (default) feeds the [0, 1] images straight into the network, as DNGaussian,
  FSGS and CoR-GS (`lpipsPyTorch`) and FreeNeRF's eval do; convention="official" feeds 2x-1 as the
  `lpips` package documents. See docs/metrics.md.
* `avge` = geometric mean of (10^(-PSNR/10), sqrt(1 - SSIM), LPIPS), per image (FreeNeRF).
* With a mask, `ssim` and `lpips` use the DTU convention: both images are composited over white
  outside the mask (img * m + (1 - m)) before the metric. `dtu_metrics` bundles the three.

The ONNX model is found from the `model` argument, else the `REINGS_LPIPS_MODEL` environment
variable, else `lpips_<net>.onnx` in the user cache's models folder (`find_lpips_model`); never
the working directory. `lpips_model_info` gives its path and sha256 (recorded in metrics.json).
"""
from __future__ import annotations

import math
import os
import threading
from pathlib import Path

import numpy as np

__all__ = [
    "psnr",
    "ssim",
    "lpips",
    "avge",
    "dtu_metrics",
    "evaluate_images",
    "find_lpips_model",
    "LPIPSModelNotFound",
]


# --------------------------------------------------------------------------------------------
# input checks


def _as_image(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{name}: expected an (H, W, 3) image, got shape {a.shape}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name}: empty image of shape {a.shape}")
    if a.dtype == np.uint8:
        raise ValueError(f"{name}: expected float values in [0, 1], got uint8 (divide by 255)")
    if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer) and a.dtype != bool:
        raise ValueError(f"{name}: expected a float image, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    if not np.all(np.isfinite(a)):
        n = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        raise ValueError(f"{name}: {n} non-finite value(s) (NaN or Inf) in the image")
    return np.clip(a, 0.0, 1.0)


def _pair(img, ref) -> tuple[np.ndarray, np.ndarray]:
    a = _as_image(img, "img")
    b = _as_image(ref, "ref")
    if a.shape != b.shape:
        raise ValueError(f"img and ref shapes differ: {a.shape} vs {b.shape}")
    return a, b


def _as_mask(mask, shape, name: str = "mask") -> np.ndarray:
    """(H, W) or (H, W, 1) mask -> float64 (H, W) in [0, 1] (bool masks as 0 / 1), the soft mask
    the DTU protocol composites with (img * m + 1 - m); its foreground (masked PSNR) is where it is
    exactly 1 (`_foreground`), DNGaussian / CoR-GS `metrics_dtu.py` (`mask == 1.` of the mask
    resized by Pillow: reings.data.images.eval_mask)."""
    m = np.asarray(mask)
    if m.ndim == 3 and m.shape[2] == 1:
        m = m[..., 0]
    if m.shape != tuple(shape[:2]):
        raise ValueError(f"{name}: expected shape {tuple(shape[:2])} (H, W), got {np.asarray(mask).shape}")
    if m.dtype != bool:
        m = m.astype(np.float64)
        if not np.all(np.isfinite(m)):
            raise ValueError(f"{name}: non-finite values in the mask")
        if m.min() < 0 or m.max() > 1:
            raise ValueError(f"{name}: values outside [0, 1] (min {m.min():g}, max {m.max():g})")
    return m.astype(np.float64)


def _foreground(mask, shape) -> np.ndarray:
    """The masked-PSNR pixels: those whose mask is exactly 1 (DNGaussian's `mask == 1.`)."""
    return _as_mask(mask, shape) >= 1.0


def _composite_white(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    return a * m[..., None] + (1.0 - m[..., None])


# --------------------------------------------------------------------------------------------
# PSNR


def psnr(img, ref, mask=None) -> float:
    """PSNR in dB of `img` against `ref`, -10 log10(MSE). `mask` (H, W) in [0, 1]: MSE over the
    foreground pixels only, those where the mask is exactly 1 (DTU protocol). Identical images give
    +inf."""
    a, b = _pair(img, ref)
    d2 = (a - b) ** 2
    if mask is None:
        mse = float(d2.mean())
    else:
        m = _foreground(mask, a.shape)
        if not m.any():
            raise ValueError("mask: no foreground pixel, PSNR is undefined")
        mse = float(d2[m].mean())
    if mse == 0.0:
        return math.inf
    return float(-10.0 * math.log10(mse))


# --------------------------------------------------------------------------------------------
# SSIM


def _gauss_1d(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def _sep_filter(x: np.ndarray, w: np.ndarray, pad_mode: str) -> np.ndarray:
    """Separable 'same'-size correlation of each channel of x (H, W, C) with the 1-D kernel w
    along both axes. pad_mode: 'constant' (zero padding, as torch conv2d) or 'symmetric'
    (scipy.ndimage 'reflect')."""
    k = w.shape[0]
    r = k // 2
    H, W = x.shape[:2]
    p = np.pad(x, ((r, k - 1 - r), (0, 0), (0, 0)), mode=pad_mode)
    y = np.zeros_like(x)
    for i in range(k):
        y += w[i] * p[i : i + H]
    p = np.pad(y, ((0, 0), (r, k - 1 - r), (0, 0)), mode=pad_mode)
    z = np.zeros_like(x)
    for i in range(k):
        z += w[i] * p[:, i : i + W]
    return z


def _ssim_map(a, b, w, pad_mode, cov_norm=1.0, C1=0.01**2, C2=0.03**2):
    mu_a = _sep_filter(a, w, pad_mode)
    mu_b = _sep_filter(b, w, pad_mode)
    saa = cov_norm * (_sep_filter(a * a, w, pad_mode) - mu_a * mu_a)
    sbb = cov_norm * (_sep_filter(b * b, w, pad_mode) - mu_b * mu_b)
    sab = cov_norm * (_sep_filter(a * b, w, pad_mode) - mu_a * mu_b)
    num = (2 * mu_a * mu_b + C1) * (2 * sab + C2)
    den = (mu_a**2 + mu_b**2 + C1) * (saa + sbb + C2)
    return num / den


def ssim(img, ref, kind: str = "gs", mask=None) -> float:
    """SSIM of `img` against `ref`.

    kind="gs": 3DGS / DNGaussian `utils/loss_utils.py` ssim (Gaussian 11x11, sigma 1.5, zero-padded
    same-size convolution per channel, mean of the whole map). kind="skimage" (alias "sk"):
    equals `skimage.metrics.structural_similarity(img, ref, data_range=1, channel_axis=-1)`.
    `mask` (H, W): both images are composited over white outside the mask first (DTU protocol).
    """
    a, b = _pair(img, ref)
    if mask is not None:
        m = _as_mask(mask, a.shape)
        a, b = _composite_white(a, m), _composite_white(b, m)
    kind = str(kind).lower()
    if kind in ("gs", "3dgs", "gaussian"):
        return float(_ssim_map(a, b, _gauss_1d(11, 1.5), "constant").mean())
    if kind in ("skimage", "sk", "sklearn"):
        win = 7
        if min(a.shape[:2]) < win:
            raise ValueError(f"ssim(kind='skimage') needs images of at least {win}x{win}, got {a.shape[:2]}")
        npix = win * win
        S = _ssim_map(a, b, np.full(win, 1.0 / win), "symmetric", cov_norm=npix / (npix - 1.0))
        pad = (win - 1) // 2
        return float(S[pad:-pad, pad:-pad].mean())
    raise ValueError(f"ssim: unknown kind {kind!r} (use 'gs' or 'skimage')")


# --------------------------------------------------------------------------------------------
# LPIPS (onnxruntime)


class LPIPSModelNotFound(FileNotFoundError):
    """No lpips_*.onnx could be found; the message lists where reings looked."""


def _candidate_paths(net: str) -> list[Path]:
    """The one implicit place: the user cache, `reings.io.files.cache_dir("models")`
    ($REINGS_CACHE_DIR/models, else $XDG_CACHE_HOME/reings/models, else ~/.cache/reings/models).
    Never the working directory nor a development folder: a stray lpips_vgg.onnx there must not
    silently replace the metric (issue 14 item 9)."""
    from .io.files import cache_dir

    return [cache_dir("models") / f"lpips_{net}.onnx"]


def find_lpips_model(model=None, net: str = "vgg") -> Path:
    """Path of the LPIPS ONNX model: `model` if given, else $REINGS_LPIPS_MODEL, else
    `lpips_<net>.onnx` in the user cache's models folder (`_candidate_paths`)."""
    if model is not None:
        p = Path(model).expanduser()
        if not p.is_file():
            raise LPIPSModelNotFound(f"LPIPS model file {p} does not exist")
        return p
    env = os.environ.get("REINGS_LPIPS_MODEL")
    if env:
        p = Path(env).expanduser()
        if not p.is_file():
            raise LPIPSModelNotFound(f"REINGS_LPIPS_MODEL={env}: file does not exist")
        return p
    cands = _candidate_paths(net)
    for c in cands:
        if c.is_file():
            return c
    raise LPIPSModelNotFound(
        f"lpips_{net}.onnx not found. Pass lpips(..., model=PATH), set REINGS_LPIPS_MODEL, or put it at "
        + ", ".join(str(c) for c in cands)
    )


def load_lpips_model(model=None, net: str = "vgg") -> Path:
    """Find the LPIPS model (`find_lpips_model`) and load it now: a file that is not an LPIPS ONNX
    model is a ValueError naming it before any work, not after a run's training. Returns its path."""
    p = find_lpips_model(model, net)
    _lpips_session(p)
    return p


_SHA256: dict[tuple, str] = {}


def lpips_model_info(model=None, net: str = "vgg") -> dict:
    """{"path", "sha256", "net"} of the model `lpips` would use (metrics.json records it)."""
    import hashlib

    p = find_lpips_model(model, net).resolve()
    st = p.stat()
    key = (str(p), st.st_size, st.st_mtime_ns)
    if key not in _SHA256:
        h = hashlib.sha256()
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _SHA256[key] = h.hexdigest()
    return {"path": str(p), "sha256": _SHA256[key], "net": net}


_SESSIONS: dict[tuple, object] = {}
_SESSION_LOCK = threading.Lock()


def _lpips_session(path: Path):
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    with _SESSION_LOCK:
        s = _SESSIONS.get(key)
        if s is not None:
            return s
        try:
            import onnxruntime as ort
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("reings.metrics.lpips needs onnxruntime (pip install onnxruntime)") from e
        so = ort.SessionOptions()
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        so.log_severity_level = 3
        try:
            s = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise ValueError(f"{path}: cannot load the LPIPS ONNX model: {e}") from e
        names = sorted(i.name for i in s.get_inputs())
        if names != ["in0", "in1"]:
            raise ValueError(f"{path}: not an LPIPS model of the expected interface (inputs in0, in1; got {names})")
        _SESSIONS[key] = s
        return s


def lpips(img, ref, model=None, convention: str = "3dgs", net: str = "vgg", mask=None) -> float:
    """LPIPS v0.1 (VGG by default) of `img` against `ref`, through onnxruntime.

    convention="3dgs" (default): the [0, 1] images go into the network as they are, which is what
    the 3DGS-family metric scripts (DNGaussian, FSGS, CoR-GS: lpipsPyTorch) and FreeNeRF's eval
    do, and so what their published LPIPS numbers mean. convention="official": 2x-1, the input
    range the `lpips` package documents. `model`: path of the .onnx (see `find_lpips_model`).
    `mask` (H, W): both images composited over white outside the mask first (DTU protocol).
    """
    a, b = _pair(img, ref)
    if mask is not None:
        m = _as_mask(mask, a.shape)
        a, b = _composite_white(a, m), _composite_white(b, m)
    conv = str(convention).lower()
    if conv in ("3dgs", "01", "raw"):
        scale, shift = 1.0, 0.0
    elif conv in ("official", "-1,1", "pm1"):
        scale, shift = 2.0, -1.0
    else:
        raise ValueError(f"lpips: unknown convention {convention!r} (use '3dgs' or 'official')")
    sess = _lpips_session(find_lpips_model(model, net))

    def prep(x):
        x = x.astype(np.float32) * np.float32(scale) + np.float32(shift)
        return np.ascontiguousarray(x.transpose(2, 0, 1)[None])

    out = sess.run(None, {"in0": prep(a), "in1": prep(b)})[0]
    v = float(np.asarray(out).reshape(-1)[0])
    if not math.isfinite(v):
        raise ValueError("lpips: the network returned a non-finite value")
    return v


# --------------------------------------------------------------------------------------------
# AVGE, DTU bundle, whole test sets


def avge(psnr, ssim, lpips):
    """Geometric mean of (MSE = 10^(-PSNR/10), sqrt(1 - SSIM), LPIPS) (FreeNeRF
    `compute_avg_error`). Scalars or equally-shaped arrays (one value per image; average the
    result yourself, as the papers do, never the inputs)."""
    p = np.asarray(psnr, dtype=np.float64)
    s = np.asarray(ssim, dtype=np.float64)
    lp = np.asarray(lpips, dtype=np.float64)
    if np.any(np.isnan(p)) or np.any(np.isnan(s)) or np.any(np.isnan(lp)):
        raise ValueError("avge: NaN input")
    mse = 10.0 ** (-p / 10.0)
    dssim = np.sqrt(np.clip(1.0 - s, 0.0, None))
    with np.errstate(divide="ignore"):
        v = np.exp((np.log(mse) + np.log(dssim) + np.log(np.clip(lp, 0.0, None))) / 3.0)
    return float(v) if v.ndim == 0 else v


def dtu_metrics(img, ref, mask, lpips_model=None, convention: str = "3dgs", ssim_kind: str = "gs") -> dict:
    """DTU protocol for one image: PSNR over the mask's foreground pixels; SSIM and LPIPS on both
    images composited over white outside the mask; AVGE of the three."""
    p = psnr(img, ref, mask=mask)
    s = ssim(img, ref, kind=ssim_kind, mask=mask)
    lp = lpips(img, ref, model=lpips_model, convention=convention, mask=mask)
    return {"psnr": p, "ssim": s, "lpips": lp, "avge": avge(p, s, lp)}


def _quantize8(a: np.ndarray) -> np.ndarray:
    # torchvision save_image / PIL: clamp(x*255 + 0.5, 0, 255) truncated
    return np.floor(np.clip(a, 0.0, 1.0) * 255.0 + 0.5) / 255.0


def evaluate_images(
    preds,
    refs,
    masks=None,
    *,
    lpips_model=None,
    lpips_convention: str = "3dgs",
    with_lpips: bool = True,
    ssim_kind: str = "gs",
    quantize: bool = False,
) -> dict:
    """Metrics of a whole test set. preds / refs: sequences of (H, W, 3) images in [0, 1]; masks:
    None or a sequence of (H, W) masks (DTU protocol: masked PSNR, SSIM/LPIPS over white).

    Returns {"psnr", "ssim", "ssim_gs", "ssim_sk", "lpips", "avge": means over images,
    "per_image": {same keys: lists}, "n": count, "settings": {...}}. "ssim" is the `ssim_kind`
    variant and AVGE uses it. With with_lpips=False, LPIPS and AVGE are None. quantize=True
    rounds both images to 8 bits first, as the compared papers do by saving PNGs.
    """
    preds = list(preds)
    refs = list(refs)
    if len(preds) != len(refs):
        raise ValueError(f"evaluate_images: {len(preds)} predictions but {len(refs)} references")
    if len(preds) == 0:
        raise ValueError("evaluate_images: no images")
    if masks is not None:
        masks = list(masks)
        if len(masks) != len(preds):
            raise ValueError(f"evaluate_images: {len(masks)} masks for {len(preds)} images")
    kind = "gs" if str(ssim_kind).lower() in ("gs", "3dgs", "gaussian") else "skimage"
    if with_lpips:
        find_lpips_model(lpips_model)  # fail early with a clear message
    cols = {k: [] for k in ("psnr", "ssim", "ssim_gs", "ssim_sk", "lpips", "avge")}
    for i, (p, r) in enumerate(zip(preds, refs)):
        try:
            a, b = _pair(p, r)
        except ValueError as e:
            raise ValueError(f"image {i}: {e}") from None
        if quantize:
            a, b = _quantize8(a), _quantize8(b)
        m = None if masks is None else masks[i]
        cols["psnr"].append(psnr(a, b, mask=m))
        cols["ssim_gs"].append(ssim(a, b, "gs", mask=m))
        cols["ssim_sk"].append(ssim(a, b, "skimage", mask=m))
        cols["ssim"].append(cols["ssim_gs" if kind == "gs" else "ssim_sk"][-1])
        if with_lpips:
            lp = lpips(a, b, model=lpips_model, convention=lpips_convention, mask=m)
            cols["lpips"].append(lp)
            cols["avge"].append(avge(cols["psnr"][-1], cols["ssim"][-1], lp))
        else:
            cols["lpips"].append(None)
            cols["avge"].append(None)
    out: dict = {}
    for k, v in cols.items():
        out[k] = None if (len(v) and v[0] is None) else float(np.mean(v))
    out["per_image"] = cols
    out["n"] = len(preds)
    out["settings"] = {
        "ssim_kind": kind,
        "lpips_convention": lpips_convention if with_lpips else None,
        "lpips_model": str(find_lpips_model(lpips_model)) if with_lpips else None,
        "masked": masks is not None,
        "quantize": bool(quantize),
    }
    return out
