"""Image files in and out: the only module that imports `cv2`.

Owns reading an image file as float32 RGB in [0, 1] (8- or 16-bit, grey, RGB or RGBA), the
structural checks that turn a truncated or undecodable file into a `SceneError` naming it,
area resizing (`cv2.INTER_AREA`, the filter RegNeRF/FreeNeRF and the LLFF `images_N` folders use),
masks, and writing 8-bit PNGs (for COLMAP in `sfm.py`). Camera intrinsics are left to the
loaders; `resize` only reports the scale factors they need.
"""
from __future__ import annotations

import functools
import os

import numpy as np

from .types import SceneError

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".exr")


def _cv2():
    try:
        import cv2
    except ImportError as e:  # pragma: no cover - exercised only without the extra
        raise SceneError("reading images needs opencv: pip install 'reings[data]' (opencv-python-headless)") from e
    return cv2


def list_images(folder: str) -> list[str]:
    """Image file names (not paths) in `folder`, sorted by name. Hidden files are skipped."""
    if not os.path.isdir(folder):
        raise SceneError(f"{folder}: image folder not found")
    names = sorted(f for f in os.listdir(folder) if f.lower().endswith(IMAGE_EXTS) and not f.startswith(".")
                   and os.path.isfile(os.path.join(folder, f)))  # a folder named like an image is not one
    if not names:
        raise SceneError(f"{folder}: no image files ({', '.join(IMAGE_EXTS)})")
    return names


def factor_image_folder(path: str, factor: int) -> tuple[str, float]:
    """(folder, scale still to apply to its images) for downsampling factor `factor` of scene `path`.

    `images_{factor}/` if it exists (scale 1: LLFF ships pre-downsampled folders), else `images/`
    with scale 1/factor (`resize` then does it). Used by the LLFF and COLMAP loaders.
    """
    if factor and factor > 1:
        d = os.path.join(path, f"images_{factor}")
        if os.path.isdir(d):
            return d, 1.0
    d = os.path.join(path, "images")
    if not os.path.isdir(d):
        raise SceneError(f"{path}: no images_{factor}/ or images/ folder")
    return d, 1.0 / factor if factor and factor > 1 else 1.0


def _check_complete(path: str, data: bytes) -> None:
    """Cheap structural check for truncation (decoders may return a partly grey image instead)."""
    low = path.lower()
    if low.endswith(".png"):
        if not data.startswith(b"\x89PNG\r\n\x1a\n"):
            raise SceneError(f"{path}: not a PNG file (bad signature)")
        # the IEND chunk closes every complete PNG: 4-byte length 0, 'IEND', 4-byte CRC
        if data[-12:-4] != b"\x00\x00\x00\x00IEND":
            raise SceneError(f"{path}: truncated PNG (no IEND chunk at the end)")
    elif low.endswith((".jpg", ".jpeg")):
        if not data.startswith(b"\xff\xd8"):
            raise SceneError(f"{path}: not a JPEG file (no SOI marker)")
        # EOI marker; some writers pad with zeros after it, so look in the last bytes only
        if b"\xff\xd9" not in data[-64:]:
            raise SceneError(f"{path}: truncated JPEG (no EOI marker at the end)")


def read_image_raw(path: str) -> np.ndarray:
    """Decode `path` to float32 [H, W, C] in [0, 1], C in {3, 4} (RGB or RGBA, not BGR)."""
    cv2 = _cv2()
    if not os.path.isfile(path):
        raise SceneError(f"{path}: image file not found")
    with open(path, "rb") as f:
        data = f.read()
    if not data:
        raise SceneError(f"{path}: empty image file")
    _check_complete(path, data)
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV's limit (CV_IO_MAX_IMAGE_PIXELS)
        raise SceneError(f"{path}: cannot decode image ({str(e).strip().splitlines()[-1]})") from None
    if img is None:
        raise SceneError(f"{path}: cannot decode image (corrupt or unsupported format)")
    if img.dtype == np.uint8:
        out = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        out = img.astype(np.float32) / 65535.0
    elif img.dtype in (np.float32, np.float64):
        out = img.astype(np.float32)
    else:
        raise SceneError(f"{path}: unsupported pixel type {img.dtype}")
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    elif out.shape[2] == 1:
        out = np.repeat(out, 3, axis=2)
    elif out.shape[2] == 3:
        out = out[:, :, ::-1]  # BGR -> RGB
    elif out.shape[2] == 4:
        out = out[:, :, [2, 1, 0, 3]]  # BGRA -> RGBA
    else:
        raise SceneError(f"{path}: unsupported channel count {out.shape[2]}")
    if not np.all(np.isfinite(out)):
        raise SceneError(f"{path}: image contains non-finite values")
    return np.ascontiguousarray(out)


def read_image(path: str) -> np.ndarray:
    """float32 RGB [H, W, 3] in [0, 1]; an alpha channel is dropped (see `read_rgba`)."""
    return np.ascontiguousarray(read_image_raw(path)[:, :, :3])


def read_rgba(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(rgb [H, W, 3], alpha [H, W] or None) as float32 in [0, 1]."""
    img = read_image_raw(path)
    if img.shape[2] == 4:
        return np.ascontiguousarray(img[:, :, :3]), np.ascontiguousarray(img[:, :, 3])
    return img, None


def read_mask(path: str) -> np.ndarray:
    """float32 [H, W] in [0, 1]: max over the colour channels (DTU/IDR masks are 3-channel 0/255)."""
    img = read_image_raw(path)
    return np.ascontiguousarray(img[:, :, :3].max(axis=2))


def eval_mask(mask_rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """The DTU evaluation mask of DNGaussian / CoR-GS `metrics_dtu.py`: each colour channel of the
    8-bit mask resized by Pillow's default filter (`resize_u8_pil`), then the minimum over the
    channels, float32 [height, width] in [0, 1] (k / 255). A pixel is foreground where it is
    exactly 1 (all three channels stayed 255); outside, the images are composited over white with
    this soft mask (reings.metrics). `mask_rgb`: [H, W, 3] (or [H, W]) float in [0, 1] from an
    8-bit file, or uint8."""
    a = np.asarray(mask_rgb)
    if a.dtype != np.uint8:
        a = np.clip(np.rint(np.asarray(a, np.float64) * 255.0), 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[:, :, None]
    chans = [resize_u8_pil(np.ascontiguousarray(a[:, :, c]), width, height) for c in range(min(a.shape[2], 3))]
    return np.ascontiguousarray(np.min(np.stack(chans), axis=0).astype(np.float32) / 255.0)


def resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area resize to (height, width) (cv2.INTER_AREA; exact box filter for integer factors).

    With pixel centres at +0.5 the intrinsics scale exactly: fx, cx by width/old_width and fy, cy
    by height/old_height.
    """
    cv2 = _cv2()
    if img.shape[1] == width and img.shape[0] == height:
        return img
    out = cv2.resize(np.ascontiguousarray(img), (int(width), int(height)), interpolation=cv2.INTER_AREA)
    if img.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    return np.ascontiguousarray(out.astype(np.float32))


# {{{ PIL's default resize of an 8-bit image (BICUBIC), exactly: the DTU evaluation masks
# DNGaussian / CoR-GS `metrics_dtu.py` resize each mask with PIL's `Image.resize(gt.size)`, whose
# default filter for 8-bit images is BICUBIC, and count as foreground only the pixels that stay
# exactly 255. This is Pillow's `Resample.c` (precompute_coeffs, normalize_coeffs_8bpc,
# ImagingResampleHorizontal/Vertical_8bpc) in numpy: double coefficients of the a = -0.5 cubic
# with its support widened by the scale, rounded to 22-bit fixed point, a horizontal pass to an
# 8-bit image, then a vertical one, each rounded and clipped to [0, 255].
_PIL_PRECISION_BITS = 32 - 8 - 2


def _pil_bicubic(x: np.ndarray) -> np.ndarray:
    a = -0.5
    x = np.abs(x)
    return np.where(x < 1.0, ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0,
                    np.where(x < 2.0, (((x - 5.0) * x + 8.0) * x - 4.0) * a, 0.0))


def _pil_coeffs(in_size: int, out_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(first input index [out], fixed-point weights [out, taps]) of one axis."""
    scale = in_size / out_size
    fscale = max(scale, 1.0)
    support = 2.0 * fscale
    taps = int(np.ceil(support)) * 2 + 1
    first = np.zeros(out_size, np.int64)
    k = np.zeros((out_size, taps), np.float64)
    for xx in range(out_size):
        center = (xx + 0.5) * scale
        xmin = max(int(center - support + 0.5), 0)
        xmax = min(int(center + support + 0.5), in_size) - xmin
        w = _pil_bicubic((np.arange(xmax) + xmin - center + 0.5) / fscale)
        ww = w.sum()
        first[xx] = xmin
        k[xx, :xmax] = w / ww if ww != 0.0 else w
    kk = np.where(k < 0, np.trunc(k * (1 << _PIL_PRECISION_BITS) - 0.5),
                  np.trunc(k * (1 << _PIL_PRECISION_BITS) + 0.5)).astype(np.int64)
    return first, kk


@functools.lru_cache(maxsize=16)
def _pil_matrix(in_size: int, out_size: int):
    """The pass of one axis as a sparse [in, out] matrix of the fixed-point weights (integers held
    in float64: every sum of a pass, at most 255 * 2^22 * taps, is an exact float64 integer)."""
    from scipy.sparse import csr_matrix

    first, kk = _pil_coeffs(in_size, out_size)
    cols = np.repeat(np.arange(out_size), kk.shape[1])
    rows = (first[:, None] + np.arange(kk.shape[1])[None, :]).ravel()
    w = kk.ravel().astype(np.float64)
    keep = (w != 0) & (rows < in_size)
    return csr_matrix((w[keep], (rows[keep], cols[keep])), shape=(in_size, out_size))


def _pil_pass(img: np.ndarray, out_size: int) -> np.ndarray:
    """One 8-bit pass along axis 1 of [rows, cols] uint8: the fixed-point sums, + 2^21, >> 22
    (floor), clipped to [0, 255], as Pillow's clip8."""
    acc = (_pil_matrix(img.shape[1], out_size).T @ img.astype(np.float64).T).T
    return np.clip(np.floor((acc + (1 << (_PIL_PRECISION_BITS - 1))) / (1 << _PIL_PRECISION_BITS)),
                   0, 255).astype(np.uint8)


def resize_u8_pil(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """[H, W] uint8 -> [height, width] uint8, bit for bit what Pillow's `Image.resize((width,
    height))` gives for an 8-bit image (filter BICUBIC, its default): tests/test_data_loaders.py
    checks it against Pillow."""
    a = np.asarray(img)
    if a.dtype != np.uint8 or a.ndim != 2:
        raise ValueError(f"resize_u8_pil: expected an [H, W] uint8 image, got {a.dtype} {a.shape}")
    if a.shape[1] != width:
        a = _pil_pass(a, int(width))
    if a.shape[0] != height:
        a = _pil_pass(a.T, int(height)).T
    return np.ascontiguousarray(a)
# }}}


def write_png(path: str, img: np.ndarray) -> None:
    """Write float RGB [H, W, 3] (or grey [H, W]) in [0, 1] as an 8-bit PNG."""
    cv2 = _cv2()
    a = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
    u8 = np.round(a * 255.0).astype(np.uint8)
    if u8.ndim == 3:
        u8 = u8[:, :, ::-1]  # RGB -> BGR
    if not cv2.imwrite(path, np.ascontiguousarray(u8)):
        raise SceneError(f"{path}: could not write PNG")
