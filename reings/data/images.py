"""Image files in and out: the only module that imports `cv2`.

Owns reading an image file as float32 RGB in [0, 1] (8- or 16-bit, grey, RGB or RGBA), the
structural checks that turn a truncated or undecodable file into a `SceneError` naming it,
area resizing (`cv2.INTER_AREA`, the filter RegNeRF/FreeNeRF and the LLFF `images_N` folders use),
masks, and writing 8-bit PNGs (for COLMAP in `sfm.py`). Camera intrinsics are left to the
loaders; `resize` only reports the scale factors they need.
"""
from __future__ import annotations

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


def write_png(path: str, img: np.ndarray) -> None:
    """Write float RGB [H, W, 3] (or grey [H, W]) in [0, 1] as an 8-bit PNG."""
    cv2 = _cv2()
    a = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
    u8 = np.round(a * 255.0).astype(np.uint8)
    if u8.ndim == 3:
        u8 = u8[:, :, ::-1]  # RGB -> BGR
    if not cv2.imwrite(path, np.ascontiguousarray(u8)):
        raise SceneError(f"{path}: could not write PNG")
