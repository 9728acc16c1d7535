"""DTU scans: the IDR/NeuS format (`cameras_sphere.npz`) and RegNeRF's (`Calibration/cal18/pos_*.txt`).

IDR/NeuS: `world_mat_i` is view i's 3x4 DTU projection matrix at 1600x1200 (padded to 4x4) and
`scale_mat_i` maps the unit sphere around the object to DTU world units. NeuS composes
P = world_mat @ scale_mat and decomposes P = K [R | t]; this module does the same decomposition
(`decompose_projection`, an RQ decomposition equal to OpenCV's `decomposeProjectionMatrix`)
with numpy, so the scene is in the unit-sphere frame by default (`normalize=False` keeps DTU
millimetres). Per-view near/far bounds are |C| -/+ the sphere radius (1 in the normalised frame).

RegNeRF: `Calibration/cal18/pos_{i+1:03d}.txt` (3x4 P at 1600x1200) next to `Rectified/scanX/`
images `rect_{i+1:03d}_{light}_r5000.png`; found from the scan folder or up to two parents.
`Cameras/*.txt` holding either a 3x4 P or MVSNet's `extrinsic`/`intrinsic` blocks is read the same
way (its K is assumed to be at `calib_size`; not checked against a real MVSNet folder here).
RegNeRF itself recentres and rescales these poses; this loader keeps the calibration frame
(normalised by the camera centres' mean and max distance when `normalize=True`).

Images: view i is the i-th image by sorted name. `factor` counts from 1600x1200 (4 -> 400x300,
the few-shot protocol). Masks (IDR/NeuS `mask/`, `masks/`, or `../masks/<scan>/` /
`../idrmasks/<scan>/[mask/]`) are evaluation data only (never seen by training): resized to the
image size as DNGaussian's `metrics_dtu.py` does (Pillow's default BICUBIC filter per colour
channel, exactly: `images.eval_mask`), kept as float32 k/255 in [0, 1]; the metrics count as
foreground the pixels that are exactly 1 and composite over white with the soft mask.
"""
from __future__ import annotations

import glob
import os
import re

import numpy as np

from . import images as imgs
from .types import Scene, SceneError, make_camera

CALIB_SIZE = (1600, 1200)  # (width, height) at which DTU's projection matrices are given


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K [3, 3] with K[2, 2] = 1 and positive diagonal, viewmat [4, 4]) from a 3x4 P = K [R | t]."""
    P = np.asarray(P, dtype=np.float64)[:3, :4]
    M = P[:, :3]
    if not np.all(np.isfinite(P)) or abs(np.linalg.det(M)) < 1e-12:
        raise ValueError("projection matrix is singular or not finite")
    # RQ via QR of the row-reversed transpose: M = K R with K upper triangular, R orthonormal
    J = np.flipud(np.eye(3))
    Q, U = np.linalg.qr((J @ M).T)
    K = J @ U.T @ J
    R = J @ Q.T
    S = np.diag(np.sign(np.diag(K)))  # make K's diagonal positive (S @ S = I)
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:  # P and -P are the same projection; pick the proper rotation
        R = -R
    C = -np.linalg.solve(M, P[:, 3])  # camera centre, independent of P's scale and sign
    K = K / K[2, 2]
    V = np.eye(4)
    V[:3, :3] = R
    V[:3, 3] = -R @ C
    return K, V


def find_regnerf_calibration(path: str) -> str | None:
    """The `Calibration/cal18` (or `Cameras`) folder for scan folder `path`, searching up two parents."""
    p = os.path.abspath(path)
    for _ in range(3):
        for sub in (("Calibration", "cal18"), ("Cameras",)):
            d = os.path.join(p, *sub)
            if os.path.isdir(d) and glob.glob(os.path.join(d, "*.txt")):
                return d
        p = os.path.dirname(p)
    return None


def _read_txt_camera(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(K, viewmat) from a DTU pos_*.txt (3x4 P) or an MVSNet cam.txt (extrinsic + intrinsic)."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as e:
        raise SceneError(f"{path}: cannot read ({e})") from e
    try:
        if "extrinsic" in text:
            nums = [float(v) for v in text.split("extrinsic", 1)[1].split("intrinsic")[0].split()]
            E = np.array(nums[:16]).reshape(4, 4)
            K = np.array([float(v) for v in text.split("intrinsic", 1)[1].split()[:9]]).reshape(3, 3)
            if not (np.all(np.isfinite(E)) and np.all(np.isfinite(K))):
                raise ValueError("non-finite value")
            return K / K[2, 2], E
        nums = [float(v) for v in text.split()]
        if len(nums) < 12:
            raise ValueError(f"expected a 3x4 projection matrix, found {len(nums)} numbers")
        return decompose_projection(np.array(nums[:12]).reshape(3, 4))
    except ValueError as e:
        raise SceneError(f"{path}: bad camera file ({e})") from e


def _image_folder(path: str, factor: int) -> str:
    cands = [f"images_{factor}", "image", "images", "rgb"] + sorted(
        os.path.basename(d) for d in glob.glob(os.path.join(path, "images_*"))
    )
    for c in cands:
        d = os.path.join(path, c)
        if os.path.isdir(d):
            return d
    if glob.glob(os.path.join(path, "rect_*.png")):
        return path
    raise SceneError(f"{path}: no DTU image folder (images_{factor}/, image/, images/ or rect_*.png)")


def _matrix(cams, key: str, npz_path: str, image: str) -> np.ndarray:
    """Entry `key` of a cameras npz as a float64 4x4 (3x4 is padded), or a SceneError naming the
    file, the entry and the image: object arrays (refused by allow_pickle=False), strings, complex
    numbers, other shapes."""
    where = f"{npz_path} ({key}, {image})"
    try:
        a = cams[key]
    except Exception as e:  # e.g. "Object arrays cannot be loaded when allow_pickle=False"
        raise SceneError(f"{where}: cannot read ({e})") from None
    if a.dtype.kind not in "fiu":
        raise SceneError(f"{where}: expected real numbers, got dtype {a.dtype}")
    if a.shape == (3, 4):
        a = np.vstack([a, [0, 0, 0, 1]])
    if a.shape != (4, 4):
        raise SceneError(f"{where}: expected a 4x4 (or 3x4) matrix, got shape {a.shape}")
    return a.astype(np.float64)


def _mask_folder(path: str) -> str | None:
    scan = os.path.basename(os.path.normpath(path))
    parent = os.path.dirname(os.path.abspath(path))
    for d in (os.path.join(path, "mask"), os.path.join(path, "masks"),
              os.path.join(parent, "masks", scan), os.path.join(parent, "idrmasks", scan, "mask"),
              os.path.join(parent, "idrmasks", scan)):
        if os.path.isdir(d) and _images_or_none(d):
            return d
    return None


def _images_or_none(d: str):
    try:
        return imgs.list_images(d)
    except SceneError:
        return None


def load_dtu(path: str, factor: int | None = 4, normalize: bool = True, light: int = 3,
             calib_size=CALIB_SIZE, load_masks: bool = True) -> Scene:
    """A DTU scan folder (IDR/NeuS `cameras_sphere.npz`, or RegNeRF calibration) as a `Scene`."""
    factor = 4 if factor is None else int(factor)
    W0, H0 = calib_size
    folder = _image_folder(path, factor)
    names = imgs.list_images(folder)
    if folder == path or os.path.basename(folder) not in (f"images_{factor}",):
        light_names = [n for n in names if re.search(rf"_{light}_r5000", n)]
        names = light_names or names
    npz_path = next((os.path.join(path, f) for f in ("cameras_sphere.npz", "cameras.npz")
                     if os.path.isfile(os.path.join(path, f))), None)
    Ks, Vs, centres_scale = [], [], None
    if npz_path is not None:
        try:
            cams = np.load(npz_path, allow_pickle=False)
            keys = set(cams.files)
        except Exception as e:
            raise SceneError(f"{npz_path}: cannot read ({e})") from e
        n_cams = len([k for k in keys if re.fullmatch(r"world_mat_\d+", k)])
        if n_cams != len(names):
            raise SceneError(f"{npz_path}: {n_cams} cameras but {len(names)} images in {folder}")
        for i in range(n_cams):
            where = f"{npz_path} (world_mat_{i}, {names[i]})"
            if f"world_mat_{i}" not in keys:
                raise SceneError(f"{npz_path}: world_mat_{i} missing")
            P = _matrix(cams, f"world_mat_{i}", npz_path, names[i])
            if normalize and f"scale_mat_{i}" in keys:
                P = P @ _matrix(cams, f"scale_mat_{i}", npz_path, names[i])
            if not np.all(np.isfinite(P)):
                raise SceneError(f"{where}: non-finite (NaN/inf) value in the projection matrix")
            try:
                K, V = decompose_projection(P[:3, :4])
            except ValueError as e:
                raise SceneError(f"{where}: {e}") from e
            Ks.append(K)
            Vs.append(V)
        radius = 1.0 if normalize and "scale_mat_0" in keys else None
    else:
        cal = find_regnerf_calibration(path)
        if cal is None:
            raise SceneError(f"{path}: no cameras_sphere.npz / cameras.npz and no Calibration/cal18 or Cameras/")
        files = sorted(glob.glob(os.path.join(cal, "pos_*.txt"))) or sorted(glob.glob(os.path.join(cal, "*.txt")))
        files = [f for f in files if re.search(r"\d", os.path.basename(f))]
        if len(files) < len(names):
            raise SceneError(f"{cal}: {len(files)} camera files but {len(names)} images in {folder}")
        files = files[: len(names)]
        for f in files:
            K, V = _read_txt_camera(f)
            Ks.append(K)
            Vs.append(V)
        if normalize:  # centre on the mean camera centre, scale so the farthest camera is at distance 1
            C = np.array([-V[:3, :3].T @ V[:3, 3] for V in Vs])
            centre = C.mean(axis=0)
            s = np.max(np.linalg.norm(C - centre, axis=1))
            centres_scale = (centre, s)
            for V in Vs:
                R, Cc = V[:3, :3], (-V[:3, :3].T @ V[:3, 3] - centre) / s
                V[:3, 3] = -R @ Cc
        radius = None
    ims, cameras = [], []
    for i, (n, K, V) in enumerate(zip(names, Ks, Vs)):
        im = imgs.read_image(os.path.join(folder, n))
        h, w = im.shape[:2]
        if abs((w / h) / (W0 / H0) - 1) > 0.02:
            raise SceneError(f"{os.path.join(folder, n)}: {w}x{h} does not have DTU's {W0}x{H0} aspect")
        tw, th = round(W0 / factor), round(H0 / factor)
        if (w, h) != (tw, th):
            im = imgs.resize(im, tw, th)
        K = K.copy()
        K[0] *= tw / W0
        K[1] *= th / H0
        ims.append(im)
        cameras.append(make_camera(K, V, tw, th, f"{npz_path or path} (view {i}, {n})"))
    bounds = None
    if radius is not None:
        d = np.array([np.linalg.norm(c.center) for c in cameras])
        bounds = np.stack([np.maximum(d - radius, 0.05), d + radius], axis=1)
    masks = None
    mdir = _mask_folder(path) if load_masks else None
    if mdir is not None:
        mnames = imgs.list_images(mdir)
        if len(mnames) != len(names):
            raise SceneError(f"{mdir}: {len(mnames)} masks but {len(names)} images")
        masks = []
        for mn, im in zip(mnames, ims):
            mp = os.path.join(mdir, mn)
            m = imgs.read_image_raw(mp)[:, :, :3]
            mh, mw = m.shape[:2]
            if abs((mw / mh) / (W0 / H0) - 1) > 0.02:  # the images' rule: a mask is never stretched
                raise SceneError(f"{mp}: {mw}x{mh} does not have DTU's {W0}x{H0} aspect")
            masks.append(imgs.eval_mask(m, im.shape[1], im.shape[0]))
    meta = {"factor": factor, "normalized": bool(normalize)}
    if centres_scale is not None:
        meta["scale"] = float(centres_scale[1])
    return Scene(ims, cameras, names, kind="dtu", masks=masks, bounds=bounds, source=path, meta=meta)
