"""Pluggable per-view depth priors, cached on disk.

    prior = get_depth_prior("onnx:/path/to/depth_anything_v2_vits.onnx")   # monocular network
    prior = get_depth_prior("stereo")                                      # built-in MVS, no network
    prior = get_depth_prior("none")                                        # no prior
    depths = prior.compute(train_scene)                       # list of (H, W) float32, or Nones
    depths, confs = prior.compute(train_scene, return_confidence=True)

`compute` takes the *training* scene only (a `reings.data.Scene`, or anything with
`.images` and `.cameras`; a plain list of images works for the ONNX prior). Every returned map is
"depth-like": larger = farther, defined up to an affine map (the depth losses are scale- and
shift-invariant per patch). The stereo prior returns metric z-depth and a confidence in [0, 1];
the ONNX prior returns confidence None.

ONNX prior (`onnx:PATH`): this module is the only place reings imports onnxruntime. The model
takes one float image tensor [1, 3, h, w] (NCHW; NHWC is detected too) and returns relative
inverse depth (disparity) of shape [1, h, w] / [1, 1, h, w] / [h, w]. Preprocessing:
  * "depth_anything" (v1 and v2): RGB in [0, 1] resized keeping aspect so both sides are >= 518
    and multiples of 14 (cv2.INTER_CUBIC; 504x378 -> 686x518), ImageNet mean/std;
  * "midas" (MiDaS v3 / DPT dpt_transform): resized keeping aspect with the "minimal" rule to
    multiples of 32 around 384 (504x378 -> 512x384), mean 0.5 / std 0.5;
  * a model whose input has fixed spatial size is fed exactly that size (aspect not kept).
"auto" picks by the graph: a fixed size divisible by 14 but not 32 -> depth_anything, by 32 ->
midas; otherwise the input name, model metadata, graph name and file name are searched for
"midas"/"dpt" or "depth_anything"/"depthanything"; otherwise depth_anything (ReInGS's prior).
The output is resized back to the image size (bilinear) and converted (`conversion`):
  * "neg_disparity" (default): depth_like = 1 - (disp - min) / (max - min), affine in -disp as
    DNGaussian's 255 - PNG/255 target;
  * "inverse": depth_like = 1 / ((disp - min) / (max - min) + eps), eps = 0.05 by default.
Either is monotone in true depth; only the ordering and local affine structure are used.

Cache: one .npz per view under `cache_dir` (default $REINGS_CACHE_DIR/depth, else
$XDG_CACHE_HOME/reings/depth, else ~/.cache/reings/depth), named by a sha256 of the image
content, the prior's settings (and the ONNX file's content hash; for stereo every training
view's image and camera). Files are written atomically (temp file + rename); an unreadable cache
file is recomputed.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from .cachekey import hash_image, hash_rounded

__all__ = [
    "DepthPrior",
    "DepthPriorError",
    "NoDepthPrior",
    "OnnxDepthPrior",
    "StereoDepthPrior",
    "get_depth_prior",
    "prior_kind",
    "default_cache_dir",
    "da_input_size",
    "midas_input_size",
]

CACHE_VERSION = 3  # 2: machine-independent keys (reings/data/cachekey.py); 3: stereo keys hold every setting
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class DepthPriorError(ValueError):
    """Bad depth-prior input: unknown kind, unreadable model file, malformed scene."""


def default_cache_dir() -> Path:
    from ..io.files import cache_dir

    return cache_dir("depth")


# --------------------------------------------------------------------------------------------
# scene access


def _views(scene, need_cameras: bool):
    if hasattr(scene, "images"):
        images = list(scene.images)
        cameras = list(getattr(scene, "cameras", None) or [])
        names = list(getattr(scene, "names", None) or [str(i) for i in range(len(images))])
        points = getattr(scene, "points", None)
        if getattr(scene, "points_from_all_views", False):
            points = None  # full-view points would leak non-training views into the prior
        bounds = getattr(scene, "bounds", None)  # each training view's own near/far
    elif isinstance(scene, (list, tuple)):
        images, cameras, names, points, bounds = list(scene), [], [str(i) for i in range(len(scene))], None, None
    else:
        raise DepthPriorError(f"depth prior: expected a Scene or a list of images, got {type(scene).__name__}")
    if not images:
        raise DepthPriorError("depth prior: the scene has no images")
    out = []
    for i, im in enumerate(images):
        a = np.asarray(im)
        if a.ndim != 3 or a.shape[2] != 3:
            raise DepthPriorError(f"depth prior: image {names[i]} has shape {a.shape}, expected (H, W, 3)")
        a = np.ascontiguousarray(a, dtype=np.float32)
        if not np.all(np.isfinite(a)):
            raise DepthPriorError(f"depth prior: image {names[i]} has non-finite values")
        out.append(a)
    if need_cameras and len(cameras) != len(out):
        raise DepthPriorError(f"depth prior: {len(out)} images but {len(cameras)} cameras (a posed Scene is required)")
    return out, cameras, names, (points, bounds)


def _file_sha256(path: Path, _memo: dict = {}) -> str:  # noqa: B006 - deliberate memo
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _memo:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _memo[key] = h.hexdigest()
    return _memo[key]


# --------------------------------------------------------------------------------------------
# base class + cache


class DepthPrior:
    """Base class. Subclasses implement `_settings()` and `_compute_views(...)`."""

    kind = "base"
    enabled = True

    def __init__(self, cache_dir=None, cache: bool = True):
        self.cache = bool(cache)
        self.cache_dir = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
        self.stats = {"hits": 0, "misses": 0}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._settings()})"

    # -- to implement
    def _settings(self) -> dict:
        raise NotImplementedError

    def _keys(self, images, cameras, geometry) -> list[str]:
        raise NotImplementedError

    def _compute_views(self, images, cameras, geometry, todo: list[int]) -> dict:
        raise NotImplementedError

    # -- cache
    def _path(self, key: str) -> Path:
        return self.cache_dir / f"{self.kind}-{key[:40]}.npz"

    def _load(self, key: str):
        p = self._path(key)
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                if str(z["key"]) != key:
                    return None
                depth = z["depth"].astype(np.float32)
                conf = z["confidence"].astype(np.float32) if "confidence" in z.files else None
            return depth, conf
        except Exception:  # corrupt or truncated: recompute
            return None

    def _store(self, key: str, depth, conf) -> None:
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        from ..io.files import atomic_write

        arrs = {"key": np.array(key), "depth": np.asarray(depth, np.float32)}
        if conf is not None:
            arrs["confidence"] = np.asarray(conf, np.float32)
        with atomic_write(self._path(key), binary=True) as f:
            np.savez(f, **arrs)

    # -- public
    def compute(self, scene_train, return_confidence: bool = False):
        """Depth-like maps for every view of `scene_train` (the training views only).

        Returns a list of (H, W) float32 maps; with return_confidence=True, (maps, confidences)
        where a confidence is (H, W) float32 in [0, 1] or None when the prior has none.
        """
        images, cameras, names, geometry = _views(scene_train, need_cameras=self.kind == "stereo")
        keys = self._keys(images, cameras, geometry)
        results: dict[int, tuple] = {}
        if self.cache:
            for i, k in enumerate(keys):
                got = self._load(k)
                if got is not None and got[0].shape == images[i].shape[:2]:
                    results[i] = got
        todo = [i for i in range(len(images)) if i not in results]
        self.stats["hits"] += len(images) - len(todo)
        self.stats["misses"] += len(todo)
        if todo:
            new = self._compute_views(images, cameras, geometry, todo)
            for i in todo:
                d, c = new[i]
                d = np.ascontiguousarray(d, dtype=np.float32)
                if d.shape != images[i].shape[:2]:
                    raise RuntimeError(f"depth prior produced shape {d.shape} for image {names[i]}")
                results[i] = (d, c)
                if self.cache:
                    self._store(keys[i], d, c)
        depths = [results[i][0] for i in range(len(images))]
        if return_confidence:
            return depths, [results[i][1] for i in range(len(images))]
        return depths


class NoDepthPrior(DepthPrior):
    """kind "none": `enabled` is False and `compute` returns one None per view."""

    kind = "none"
    enabled = False

    def __init__(self, **_):
        super().__init__(cache=False)

    def _settings(self) -> dict:
        return {"kind": "none"}

    def compute(self, scene_train, return_confidence: bool = False):
        n = len(scene_train.images) if hasattr(scene_train, "images") else len(scene_train)
        d = [None] * n
        return (d, [None] * n) if return_confidence else d


# --------------------------------------------------------------------------------------------
# ONNX monocular prior


def _multiple(x: float, m: int, min_val: int = 0, max_val: int | None = None) -> int:
    """MiDaS / Depth Anything `Resize.constrain_to_multiple_of`."""
    y = int(np.round(x / m) * m)
    if max_val is not None and y > max_val:
        y = int(np.floor(x / m) * m)
    if y < min_val:
        y = int(np.ceil(x / m) * m)
    return y


def da_input_size(h: int, w: int, size: int = 518, multiple: int = 14) -> tuple[int, int]:
    """Depth Anything 'lower_bound' resize, keep aspect: (new_h, new_w), both >= size."""
    sh, sw = size / h, size / w
    s = max(sh, sw)
    return _multiple(s * h, multiple, min_val=size), _multiple(s * w, multiple, min_val=size)


def midas_input_size(h: int, w: int, size: int = 384, multiple: int = 32) -> tuple[int, int]:
    """MiDaS/DPT 'minimal' resize, keep aspect: the scale closest to 1 of the two."""
    sh, sw = size / h, size / w
    s = sw if abs(1 - sw) < abs(1 - sh) else sh
    return _multiple(s * h, multiple), _multiple(s * w, multiple)


PREPROCESS = {
    "depth_anything": {"mean": IMAGENET_MEAN, "std": IMAGENET_STD},
    "midas": {"mean": (0.5, 0.5, 0.5), "std": (0.5, 0.5, 0.5)},
}
_PRE_ALIASES = {"da": "depth_anything", "da1": "depth_anything", "da2": "depth_anything", "dpt": "midas"}


MIN_OUTPUT_SIDE = 8  # an ONNX prior's map must have at least this many pixels per side (or the image's)


class OnnxDepthPrior(DepthPrior):
    """A monocular relative-depth network run by onnxruntime (see the module docstring)."""

    kind = "onnx"

    def __init__(
        self,
        path,
        preprocess: str = "auto",
        conversion: str = "neg_disparity",
        eps: float = 0.05,
        cache_dir=None,
        cache: bool = True,
        providers=None,
    ):
        super().__init__(cache_dir=cache_dir, cache=cache)
        self.path = Path(path).expanduser()
        if conversion not in ("neg_disparity", "inverse", "disparity"):
            raise DepthPriorError(f"onnx prior: unknown conversion {conversion!r} (neg_disparity, inverse)")
        self.conversion = conversion
        self.eps = float(eps)
        if not self.path.is_file():
            raise DepthPriorError(f"{self.path}: ONNX depth model not found")
        try:
            import onnxruntime as ort
        except ImportError as e:  # pragma: no cover
            raise ImportError("the onnx depth prior needs onnxruntime (pip install onnxruntime)") from e
        so = ort.SessionOptions()
        so.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), so, providers=providers or ["CPUExecutionProvider"])
        except Exception as e:
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise DepthPriorError(f"{self.path}: not a readable ONNX model ({msg})") from None
        ins = self.session.get_inputs()
        if len(ins) != 1:
            raise DepthPriorError(
                f"{self.path}: expected a model with one image input, got {len(ins)} ({[i.name for i in ins]})"
            )
        inp = ins[0]
        self.input_name = inp.name
        shp = list(inp.shape)
        if len(shp) != 4:
            raise DepthPriorError(f"{self.path}: input {inp.name} has shape {shp}, expected 4-D [N, 3, H, W]")
        if shp[1] == 3:
            self.layout = "NCHW"
            hw = shp[2:4]
        elif shp[3] == 3:
            self.layout = "NHWC"
            hw = shp[1:3]
        else:
            raise DepthPriorError(f"{self.path}: input {inp.name} has shape {shp}, expected [N, 3, H, W] or [N, H, W, 3]")
        self.fixed_hw = tuple(int(x) for x in hw) if all(isinstance(x, int) and x > 0 for x in hw) else None
        self.input_dtype = np.float16 if "float16" in inp.type else np.float32
        self.sha256 = _file_sha256(self.path)
        pre = _PRE_ALIASES.get(str(preprocess).lower(), str(preprocess).lower())
        if pre == "auto":
            pre = self._detect()
        if pre not in PREPROCESS:
            raise DepthPriorError(f"onnx prior: unknown preprocess {preprocess!r} (auto, depth_anything, midas)")
        self.preprocess = pre

    def _detect(self) -> str:
        if self.fixed_hw is not None:
            h, w = self.fixed_hw
            if h % 14 == 0 and w % 14 == 0 and not (h % 32 == 0 and w % 32 == 0):
                return "depth_anything"
            if h % 32 == 0 and w % 32 == 0 and not (h % 14 == 0 and w % 14 == 0):
                return "midas"
        words = [self.input_name, self.path.name]
        try:
            meta = self.session.get_modelmeta()
            words += [meta.graph_name or "", meta.producer_name or "", meta.description or ""]
            words += [f"{k}={v}" for k, v in (meta.custom_metadata_map or {}).items()]
        except Exception:  # pragma: no cover
            pass
        text = " ".join(words).lower().replace("-", "_")
        if "midas" in text or "dpt" in text:
            return "midas"
        if "depth_anything" in text or "depthanything" in text:
            return "depth_anything"
        return "depth_anything"

    def _settings(self) -> dict:
        return {
            "kind": "onnx",
            "model_sha256": self.sha256,
            "preprocess": self.preprocess,
            "conversion": self.conversion,
            "eps": self.eps,
            "version": CACHE_VERSION,
        }

    def _keys(self, images, cameras, geometry) -> list[str]:
        base = json.dumps(self._settings(), sort_keys=True).encode()
        keys = []
        for im in images:
            h = hashlib.sha256(base)
            hash_image(h, im)
            keys.append(h.hexdigest())
        return keys

    def input_size(self, h: int, w: int) -> tuple[int, int]:
        """(h, w) fed to the network for an h x w image."""
        if self.fixed_hw is not None:
            return self.fixed_hw
        if self.preprocess == "depth_anything":
            return da_input_size(h, w)
        return midas_input_size(h, w)

    def prepare(self, img: np.ndarray) -> np.ndarray:
        """The network input tensor for one (H, W, 3) image in [0, 1]."""
        import cv2

        h, w = img.shape[:2]
        nh, nw = self.input_size(h, w)
        x = np.clip(img.astype(np.float32), 0.0, 1.0)
        if (nh, nw) != (h, w):
            x = cv2.resize(x, (nw, nh), interpolation=cv2.INTER_CUBIC)
        p = PREPROCESS[self.preprocess]
        x = (x - np.asarray(p["mean"], np.float32)) / np.asarray(p["std"], np.float32)
        if self.layout == "NCHW":
            x = x.transpose(2, 0, 1)
        return np.ascontiguousarray(x[None], dtype=self.input_dtype)

    def postprocess(self, out, h: int, w: int) -> np.ndarray:
        """Network output (relative inverse depth) -> (h, w) depth-like map."""
        import cv2

        d = np.asarray(out, dtype=np.float32)
        while d.ndim > 2 and d.shape[0] == 1:
            d = d[0]
        if d.ndim == 3 and d.shape[-1] == 1:
            d = d[..., 0]
        if d.ndim != 2:
            raise DepthPriorError(f"{self.path}: output shape {np.shape(out)} is not a single depth map")
        if not np.all(np.isfinite(d)):
            raise DepthPriorError(f"{self.path}: the network returned non-finite values")
        if min(d.shape) < min(MIN_OUTPUT_SIDE, h, w):
            raise DepthPriorError(f"{self.path}: output shape {np.shape(out)} is too small to be the depth map of a "
                                  f"{w}x{h} image (each side must have >= {MIN_OUTPUT_SIDE} pixels)")
        if float(d.max()) == float(d.min()):
            raise DepthPriorError(f"{self.path}: the network returned a constant map ({float(d.min())!r}); "
                                  "that is no depth")
        if d.shape != (h, w):
            d = cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR)
        if self.conversion == "disparity":
            return d.astype(np.float32)
        lo, hi = float(d.min()), float(d.max())
        dn = (d - lo) / (hi - lo) if hi > lo else np.zeros_like(d)
        if self.conversion == "neg_disparity":
            return (1.0 - dn).astype(np.float32)
        return (1.0 / (dn + self.eps)).astype(np.float32)

    def predict(self, img: np.ndarray) -> np.ndarray:
        """Depth-like map of one image, no cache."""
        h, w = img.shape[:2]
        try:
            out = self.session.run(None, {self.input_name: self.prepare(img)})[0]
        except DepthPriorError:
            raise
        except Exception as e:
            raise DepthPriorError(f"{self.path}: inference failed: {str(e).strip().splitlines()[0]}") from None
        return self.postprocess(out, h, w)

    def _compute_views(self, images, cameras, geometry, todo):
        return {i: (self.predict(images[i]), None) for i in todo}


# --------------------------------------------------------------------------------------------
# stereo prior


class StereoDepthPrior(DepthPrior):
    """Multi-view plane-sweep stereo among the training views (`reings.data.stereo`)."""

    kind = "stereo"

    def __init__(self, cache_dir=None, cache: bool = True, **options):
        super().__init__(cache_dir=cache_dir, cache=cache)
        import inspect

        from .stereo import stereo_depths

        params = inspect.signature(stereo_depths).parameters
        # use_bounds: each training view's own near/far (Scene.bounds) as its depth range, instead
        # of the range from the sparse points or the baselines (stereo.depth_range)
        self.defaults = {k: p.default for k, p in params.items()
                         if k not in ("images", "cameras", "points", "bounds", "progress")}
        self.defaults["use_bounds"] = False
        bad = set(options) - set(self.defaults)
        if bad:
            raise DepthPriorError(f"stereo prior: unknown option(s) {sorted(bad)}; known: {sorted(self.defaults)}")
        self.options = dict(options)

    def with_options(self, **options) -> "StereoDepthPrior":
        """The same prior (cache directory and switch) with these options added."""
        return StereoDepthPrior(cache_dir=self.cache_dir, cache=self.cache, **{**self.options, **options})

    def _resolved(self) -> dict:
        """Every setting, the defaults filled in."""
        return {**self.defaults, **self.options}

    def _settings(self) -> dict:
        # every setting, defaults resolved: a changed default makes new cache keys
        opts = self._resolved()
        return {"kind": "stereo", "options": {k: opts[k] for k in sorted(opts)}, "version": CACHE_VERSION}

    def _keys(self, images, cameras, geometry) -> list[str]:
        h = hashlib.sha256(json.dumps(self._settings(), sort_keys=True, default=str).encode())
        for im, cam in zip(images, cameras):  # machine-independent forms (reings/data/cachekey.py)
            hash_image(h, im)
            hash_rounded(h, cam.K, 4)
            hash_rounded(h, cam.viewmat, 6)
        points, bounds = geometry
        if points is not None:
            hash_rounded(h, points, 6)
        if bounds is not None and self._resolved()["use_bounds"]:
            h.update(b"bounds")
            hash_rounded(h, bounds, 6)
        group = h.hexdigest()
        return [hashlib.sha256(f"{group}:{i}".encode()).hexdigest() for i in range(len(images))]

    def _compute_views(self, images, cameras, geometry, todo):
        from .stereo import stereo_depths

        try:
            points, bounds = geometry
            opts = dict(self.options)
            opts.pop("use_bounds", None)
            if self._resolved()["use_bounds"]:
                opts["bounds"] = bounds
            res = stereo_depths(images, cameras, points, **opts)
        except ValueError as e:
            raise DepthPriorError(str(e)) from None
        return {i: (res[i].depth, res[i].confidence) for i in todo}


# --------------------------------------------------------------------------------------------


NO_PRIOR = ("none", "off", "no")  # the --depth-prior specs of no prior (get_depth_prior -> NoDepthPrior)


def prior_kind(spec: str) -> str:
    """The kind of a --depth-prior spec: "stereo" for "stereo" and "stereo:k=v,...", else the spec
    lower-cased up to its first ':' ("onnx", "none", "exact", ...)."""
    return str(spec).strip().lower().split(":", 1)[0]


def _stereo_spec_options(text: str) -> dict:
    """"k=v,k=v" of a 'stereo:k=v,...' spec: numbers and True/False only, each name checked by
    StereoDepthPrior."""
    import ast
    import re

    out = {}
    for kv in filter(None, re.split(r",(?=\s*\w+\s*=)", text)):
        if "=" not in kv:
            raise DepthPriorError(f"depth prior 'stereo:{text}': expected k=v pairs separated by ',', got {kv!r}")
        k, v = (x.strip() for x in kv.split("=", 1))
        try:
            val = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            val = None
        if isinstance(val, bool) or (isinstance(val, (int, float)) and math.isfinite(val)):
            out[k] = val
        else:
            raise DepthPriorError(f"depth prior 'stereo:{text}': {k}={v!r} is not a finite number or True/False")
    return out


def get_depth_prior(kind: str, cache_dir=None, cache: bool = True, **options) -> DepthPrior:
    """A depth prior from its spec string: "onnx:PATH", "stereo", "stereo:k=v,..." or "none".

    "stereo:sgm_p1=0.03,sgm_p2=0.6,use_bounds=False" sets the stereo prior's options (numbers and
    True/False; the names of `reings.data.stereo.stereo_depths`, and use_bounds); a run whose spec
    sets options keeps them over its recipe's (`reings.pipeline.STEREO_BY_FAMILY`).

    Options go to the prior: OnnxDepthPrior(preprocess="auto"|"depth_anything"|"midas",
    conversion="neg_disparity"|"inverse", eps) or stereo (see `reings.data.stereo.stereo_depths`).
    The ONNX path may also come from $REINGS_DEPTH_MODEL with kind "onnx".
    """
    if not isinstance(kind, str) or not kind:
        raise DepthPriorError(f"depth prior: expected 'onnx:PATH', 'stereo[:k=v,...]' or 'none', got {kind!r}")
    k = kind.strip()
    low = k.lower()
    if low in NO_PRIOR:
        return NoDepthPrior()
    if low == "stereo" or low.startswith("stereo:"):
        spec = _stereo_spec_options(k[7:]) if low.startswith("stereo:") else {}
        return StereoDepthPrior(cache_dir=cache_dir, cache=cache, **{**spec, **options})
    if low == "onnx" or low.startswith("onnx:"):
        path = k[5:] if low.startswith("onnx:") else os.environ.get("REINGS_DEPTH_MODEL", "")
        if not path:
            raise DepthPriorError("depth prior 'onnx' needs a model path: 'onnx:PATH' or REINGS_DEPTH_MODEL")
        bad = set(options) - {"preprocess", "conversion", "eps", "providers"}
        if bad:
            raise DepthPriorError(f"onnx prior: unknown option(s) {sorted(bad)}; known: conversion, eps, preprocess, providers")
        return OnnxDepthPrior(path, cache_dir=cache_dir, cache=cache, **options)
    raise DepthPriorError(f"depth prior: unknown kind {kind!r}; use 'onnx:PATH', 'stereo[:k=v,...]' or 'none'")
