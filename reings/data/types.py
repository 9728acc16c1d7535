"""The data vocabulary every loader shares: `Scene`, `SceneError`, `KINDS`, `make_camera`.

A `Scene` is a list of posed views: float32 RGB images in [0, 1], one `reings.Camera` per image
(K 3x3, viewmat 4x4 world-to-camera, OpenCV axes, pixel centres at +0.5), image names, and
optional per-view masks, near/far bounds and exact depths, plus optional sparse points.

Leakage guard: `Scene.subset(indices)` returns a scene that holds *only* the selected views. Every
per-view field is sliced, and the sparse points, which a dataset's COLMAP model builds from
every view, are dropped unless the caller opts in by name (`keep_full_view_points=True`, for
reproducing DNGaussian's full-view box). The training side receives `scene.subset(train)` and
nothing else; `reings.data.sfm.sfm_extent` recomputes points from the training views alone.

This module imports nothing from the rest of `reings.data`: the per-format loaders (`llff.py`,
`colmap.py`, `dtu.py`, `blender.py`, `procedural.py`) import it, and `loader.py` (format detection
and dispatch, `load_scene`) imports them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..types import Camera


class SceneError(ValueError):
    """Bad scene input: the message names the file and the problem."""


KINDS = ("llff", "llff_nex", "colmap", "dtu", "blender", "nerfstudio", "procedural")  # dataset kinds; `Scene.kind` is one


@dataclass
class Scene:
    """Posed views of one scene. Lists are indexed by view; arrays are numpy.

    images:  V x [H, W, 3] float32 RGB in [0, 1]
    cameras: V x `reings.Camera`
    names:   V x str (image file names, or "split/name" for NeRF-synthetic)
    kind:    dataset kind ("llff", "llff_nex", "colmap", "dtu", "blender", "procedural"); picks the split protocol
    masks:   V x [H, W] float32 in [0, 1] (DTU object masks, NeRF-synthetic alpha) or None
    bounds:  [V, 2] float64 per-view (near, far) depths or None
    depths:  V x [H, W] float32 exact camera-space z (procedural scene only) or None
    points:  [P, 3] float64 sparse points or None; `points_from_all_views` says whether they were
             built from every view of the dataset (a full-view COLMAP model: leakage for few-shot)
    point_colors: [P, 3] float32 in [0, 1] or None
    splits:  V x str ("train"/"val"/"test") where the dataset ships its own split (NeRF-synthetic)
    source:  path the scene was read from (informational)
    """

    images: list
    cameras: list
    names: list
    kind: str = "colmap"
    masks: list | None = None
    bounds: np.ndarray | None = None
    depths: list | None = None
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    points_from_all_views: bool = False
    splits: list | None = None
    source: str | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.images)
        if len(self.cameras) != n or len(self.names) != n:
            raise SceneError(
                f"Scene: {n} images, {len(self.cameras)} cameras, {len(self.names)} names (must be equal)"
            )
        self.images = [np.ascontiguousarray(np.asarray(im, dtype=np.float32)) for im in self.images]
        self.names = [str(s) for s in self.names]
        for i, (im, cam) in enumerate(zip(self.images, self.cameras)):
            if not isinstance(cam, Camera):
                raise SceneError(f"Scene: cameras[{i}] is {type(cam).__name__}, expected reings.Camera")
            if im.ndim != 3 or im.shape[2] != 3:
                raise SceneError(f"Scene: image {self.names[i]} has shape {im.shape}, expected (H, W, 3)")
            if im.shape[:2] != (cam.height, cam.width):
                raise SceneError(
                    f"Scene: image {self.names[i]} is {im.shape[1]}x{im.shape[0]} but its camera is "
                    f"{cam.width}x{cam.height}"
                )
        for fname in ("masks", "depths", "splits"):
            v = getattr(self, fname)
            if v is not None and len(v) != n:
                raise SceneError(f"Scene: {len(v)} {fname} for {n} images")
        if self.masks is not None:
            self.masks = [np.ascontiguousarray(np.asarray(m, dtype=np.float32)) for m in self.masks]
        if self.depths is not None:
            self.depths = [np.ascontiguousarray(np.asarray(d, dtype=np.float32)) for d in self.depths]
        if self.bounds is not None:
            b = np.asarray(self.bounds, dtype=np.float64)
            if b.shape != (n, 2):
                raise SceneError(f"Scene: bounds shape {b.shape}, expected ({n}, 2)")
            self.bounds = b
        if self.points is not None:
            p = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
            self.points = p
            if self.point_colors is not None:
                self.point_colors = np.asarray(self.point_colors, dtype=np.float32).reshape(-1, 3)

    def __len__(self) -> int:
        return len(self.images)

    def __repr__(self) -> str:
        h, w = self.images[0].shape[:2] if self.images else (0, 0)
        extra = []
        if self.masks is not None:
            extra.append("masks")
        if self.bounds is not None:
            extra.append("bounds")
        if self.depths is not None:
            extra.append("depths")
        if self.points is not None:
            extra.append(f"{len(self.points)} points" + (" (all views)" if self.points_from_all_views else ""))
        return f"Scene(kind={self.kind!r}, views={len(self)}, size={w}x{h}{', ' if extra else ''}{', '.join(extra)})"

    def subset(self, indices, keep_full_view_points: bool = False) -> "Scene":
        """A new Scene holding only the views `indices` (copies, in the given order).

        Sparse points are dropped unless they were built from these views only, or the caller
        asks for full-view points explicitly (`keep_full_view_points=True`; the result is then
        flagged `points_from_all_views=True`). `meta` keeps only scalar provenance entries.
        """
        idx = [int(i) for i in indices]
        n = len(self)
        for i in idx:
            if not 0 <= i < n:
                raise IndexError(f"Scene.subset: index {i} out of range for {n} views")
        if len(set(idx)) != len(idx):
            raise ValueError(f"Scene.subset: repeated indices {idx}")

        def pick(lst):
            return None if lst is None else [np.array(lst[i], copy=True) for i in idx]

        keep_points = self.points is not None and (
            keep_full_view_points or (not self.points_from_all_views and sorted(idx) == list(range(n)))
        )
        meta = {k: v for k, v in self.meta.items() if isinstance(v, (str, int, float, bool))}
        meta["subset_of"] = n
        return Scene(
            images=pick(self.images),
            cameras=[Camera(c.K.copy(), c.viewmat.copy(), c.width, c.height) for c in (self.cameras[i] for i in idx)],
            names=[self.names[i] for i in idx],
            kind=self.kind,
            masks=pick(self.masks),
            bounds=None if self.bounds is None else self.bounds[idx].copy(),
            depths=pick(self.depths),
            points=self.points.copy() if keep_points else None,
            point_colors=self.point_colors.copy() if keep_points and self.point_colors is not None else None,
            points_from_all_views=bool(keep_points and self.points_from_all_views),
            splits=None if self.splits is None else [self.splits[i] for i in idx],
            source=self.source,
            meta=meta,
        )


def make_camera(K, viewmat, width: int, height: int, where: str) -> Camera:
    """`Camera(...)` with non-finite or malformed input reported as a `SceneError` naming `where`."""
    K = np.asarray(K, dtype=np.float64)
    V = np.asarray(viewmat, dtype=np.float64)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(V))):
        raise SceneError(f"{where}: non-finite (NaN/inf) value in the camera pose or intrinsics")
    R = V[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or not np.linalg.det(R) > 0:
        raise SceneError(f"{where}: pose rotation is not a proper rotation (det {np.linalg.det(R):.4f})")
    try:
        return Camera(K, V, int(width), int(height))
    except ValueError as e:
        raise SceneError(f"{where}: {e}") from e
