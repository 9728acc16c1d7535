"""Fly-through videos of a finished run: `reings render` and `reings.render_path`.

    frames = reings.render_path("runs/fern", path="spiral", frames=120, device="cuda")
    frames.write("fern.mp4", fps=30)                  # OpenCV's VideoWriter (mp4v; .avi: MJPG)

A run folder holds `gaussians.ply` and `cameras.json` (reings.io.cameras); the path is built from
its training cameras (reings.paths), or the cameras of a given cameras.json are rendered as they
are. Rendering goes through the backend's `render_frames` (the model goes to the device once);
`seconds` counts rendering and the read-back of the images, not encoding.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from .types import Camera, Gaussians


@dataclass
class PathFrames:
    """A rendered camera path: 8-bit RGB frames [H,W,3], optional float depth maps, the cameras,
    and the seconds spent rendering (encoding excluded)."""

    frames: list
    cameras: list
    seconds: float
    depths: list | None = None
    device: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def fps(self) -> float:
        return len(self.frames) / self.seconds if self.seconds > 0 else float("inf")

    def write(self, path, fps: float = 30.0) -> str:
        """Encode the frames into a video file (`write_video`)."""
        return write_video(path, self.frames, fps)

    def write_depth(self, path, fps: float = 30.0) -> str:
        """Encode the depth maps, colour-mapped (`depth_colormap`), into a video file."""
        if self.depths is None:
            raise ValueError("no depth maps: render with depth=True")
        return write_video(path, depth_colormap(self.depths), fps)

    def write_frames(self, folder, prefix: str = "frame") -> list[str]:
        """One PNG per frame, `<folder>/<prefix>_0000.png`, ..."""
        from .outputs import write_png_atomic

        os.makedirs(folder, exist_ok=True)
        paths = []
        for i, im in enumerate(self.frames):
            p = os.path.join(folder, f"{prefix}_{i:04d}.png")
            write_png_atomic(p, np.ascontiguousarray(im[..., ::-1]))  # RGB -> OpenCV's BGR
            paths.append(p)
        return paths


def load_run(run_dir, members: bool = False):
    """(Gaussians, training CameraRecords) of a run folder (gaussians.ply, cameras.json); with
    members=True the first item is the list of the run's models, an ensemble's members in order
    (gaussians.ply, gaussians_member1.ply, ...: `reings.outputs.member_plys`)."""
    from .io.cameras import read_cameras_json
    from .io.ply import read_ply
    from .outputs import member_plys

    run_dir = os.fspath(run_dir)
    if not os.path.isdir(run_dir):
        raise FileNotFoundError(f"{run_dir}: run folder not found")
    ply = os.path.join(run_dir, "gaussians.ply")
    if not os.path.isfile(ply):
        raise FileNotFoundError(f"{run_dir}: no gaussians.ply (not a finished run)")
    cams = os.path.join(run_dir, "cameras.json")
    if not os.path.isfile(cams):
        raise FileNotFoundError(f"{run_dir}: no cameras.json (a run made before reings wrote it: rerun it, "
                                "or pass --cameras FILE)")
    recs = read_cameras_json(cams)
    train = [r for r in recs if r.split in ("train", "")] or recs
    if members:
        names = member_plys(run_dir)
        want = _members_scored(run_dir)
        if want is not None and want != len(names):
            raise FileNotFoundError(f"{run_dir}: metrics.json scores an ensemble of {want} models but "
                                    f"{len(names)} model file(s) are there ({', '.join(names)}): "
                                    f"gaussians_member1.ply ... gaussians_member{want - 1}.ply expected")
        return [read_ply(os.path.join(run_dir, n)) for n in names], train
    return read_ply(ply), train


def _members_scored(run_dir: str) -> int | None:
    """The ensemble's member count that the run's metrics.json scored (1 without `ensemble`), or
    None when metrics.json is absent or unreadable (the model files then say)."""
    import json

    try:
        with open(os.path.join(run_dir, "metrics.json")) as f:
            m = json.load(f)
    except (OSError, ValueError):
        return None
    ens = m.get("ensemble") if isinstance(m, dict) else None
    if not isinstance(ens, dict):
        return 1 if isinstance(m, dict) else None
    k = ens.get("members")
    return k if isinstance(k, int) and not isinstance(k, bool) and k >= 1 else None


MEMBER_CHUNK = 16  # frames of an ensemble's path rendered per member in turn (`render_path`)
MAX_SIZE = 16384  # the largest frame side `render_path` draws (and `reings render --size` takes)


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)


def render_path(model, path: str = "spiral", frames: int = 120, size: tuple[int, int] | None = None,
                cameras=None, device: str = "pocl", background=(0.0, 0.0, 0.0), near: float = 0.01,
                depth: bool = False) -> PathFrames:
    """Render a camera path of `model` (a run folder, or a `Gaussians` with `cameras`, or a list of
    them: an ensemble's members, whose frames are the mean of theirs, as the run's test renders).

    path: 'spiral' (LLFF, forward-facing), 'ellipse' (object scenes), 'interpolate' (through the
        training views), or 'cameras' to render `cameras` as given.
    cameras: the cameras to build the path from (default: the run's training cameras), a list of
        `reings.Camera`, or the path of a cameras.json.
    size: (width, height) of the frames; default the training cameras'.
    """
    from .backends import get_backend
    from .io.cameras import read_cameras_json
    from .paths import camera_path, resize

    if isinstance(model, Gaussians):
        gs, recs = [model], None
    elif isinstance(model, (list, tuple)):
        gs, recs = list(model), None
        bad = [i for i, m in enumerate(gs) if not isinstance(m, Gaussians)]
        if not gs or bad:
            raise TypeError("render_path: model must be a run folder, a reings.Gaussians or a non-empty list of them"
                            + (f" (item {bad[0]} is a {type(gs[bad[0]]).__name__})" if bad else ""))
    else:
        gs, recs = load_run(model, members=True)
    g = gs[0]
    if cameras is None:
        if recs is None:
            raise ValueError("render_path: pass cameras= with a Gaussians model")
        cams = [r.camera for r in recs]
    elif isinstance(cameras, (str, os.PathLike)):
        cams = [r.camera for r in read_cameras_json(cameras)]
    else:
        cams = list(cameras)
        bad = [i for i, c in enumerate(cams) if not isinstance(c, Camera)]
        if bad:
            raise TypeError(f"render_path: cameras[{bad[0]}] is not a reings.Camera")
    if size is not None:
        w, h = size
        if int(w) != w or int(h) != h or w < 1 or h < 1:
            raise ValueError(f"render_path: size must be two positive integers, got {size!r}")
    if path == "cameras":
        todo = [resize(c, *size) for c in cams] if size else cams
    else:
        op = 1.0 / (1.0 + np.exp(-g.opacity_logits.astype(np.float64)))
        todo = camera_path(path, cams, frames, points=g.means, weights=op * (op > 0.1), size=size)
    big = next((i for i, c in enumerate(todo) if max(c.width, c.height) > MAX_SIZE), None)
    if big is not None:  # e.g. a cameras.json entry of 10^6 pixels: say so before any buffer is sized
        src = (os.fspath(cameras) if isinstance(cameras, (str, os.PathLike)) else
               os.path.join(os.fspath(model), "cameras.json") if recs is not None and cameras is None else "cameras=")
        raise ValueError(f"render_path: frame {big} would be {todo[big].width}x{todo[big].height} (from {src}); "
                         f"frames are at most {MAX_SIZE} pixels a side: pass size= (--size WxH)")
    backend = get_backend(device)
    bg = tuple(float(x) for x in np.asarray(background, np.float32).reshape(3))  # as reings.render takes it
    t = time.perf_counter()
    out, deps = [], [] if depth else None
    for rgb, d in _model_frames(backend, gs, todo, bg, near, depth):
        out.append(_to_uint8(rgb))
        if depth:
            deps.append(d)
    secs = time.perf_counter() - t
    return PathFrames(out, todo, secs, deps, device=getattr(backend, "device_name", device),
                      meta={"path": path, "gaussians": sum(len(m) for m in gs), "members": len(gs)})


def _model_frames(backend, gs: list, cams: list, bg, near: float, depth: bool):
    """(rgb, depth or None) per camera: one model's frames as the backend renders them; an
    ensemble's, the mean of its members' clipped images (as its test renders) and depths. A
    backend holds one uploaded model at a time, so the members render in turn, MEMBER_CHUNK frames
    at a time: at most that many float frames per member are held."""
    if len(gs) == 1:
        yield from backend.render_frames(gs[0], cams, background=bg, near=near, depth=depth)
        return
    for lo in range(0, len(cams), MEMBER_CHUNK):
        rgb_sum = d_sum = None
        for m in gs:
            frames = list(backend.render_frames(m, cams[lo:lo + MEMBER_CHUNK], background=bg, near=near, depth=depth))
            rgbs = [np.clip(r, 0, 1) for r, _ in frames]
            ds = [d for _, d in frames]
            rgb_sum = rgbs if rgb_sum is None else [x + y for x, y in zip(rgb_sum, rgbs)]
            d_sum = ds if d_sum is None or not depth else [x + y for x, y in zip(d_sum, ds)]
        for r, d in zip(rgb_sum, d_sum):
            yield r / len(gs), (d / len(gs) if depth else None)


def depth_colormap(depths) -> list:
    """Colour-mapped 8-bit RGB depth frames (OpenCV's TURBO map, near = warm), one scale for the
    whole sequence: the 2nd and 98th percentiles of the positive depths over all frames."""
    import cv2

    vals = np.concatenate([d[d > 0].ravel() for d in depths]) if depths else np.zeros(0)
    lo, hi = (np.percentile(vals, [2, 98]) if vals.size else (0.0, 1.0))
    hi = hi if hi > lo else lo + 1.0
    out = []
    for d in depths:
        u = np.clip((hi - d) / (hi - lo), 0, 1)  # near -> 1
        u8 = np.rint(u * 255).astype(np.uint8)
        bgr = cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)
        bgr[d <= 0] = 0
        out.append(np.ascontiguousarray(bgr[..., ::-1]))
    return out


FOURCC = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG", ".mkv": "MJPG"}


def check_codec(path) -> None:
    """Raise OSError, before any frame is rendered, when OpenCV's VideoWriter cannot encode `path`'s
    extension on this machine (a 16x16 probe written to a temporary file beside `path`, then removed)."""
    import cv2

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FOURCC:
        raise ValueError(f"{path}: unknown video extension {ext or '(none)'!r} (use {', '.join(FOURCC)})")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.access(folder, os.W_OK):
        raise OSError(f"{path}: cannot write into the folder {folder}")
    probe = os.path.join(folder, f".tmp-{os.getpid()}-probe{ext}")
    vw = cv2.VideoWriter(probe, cv2.VideoWriter_fourcc(*FOURCC[ext]), 30.0, (16, 16))
    try:
        if not vw.isOpened():
            raise OSError(f"{path}: OpenCV's VideoWriter cannot encode {ext} ({FOURCC[ext]}) here "
                          f"(OpenCV {cv2.__version__} without that codec); try another extension, or "
                          "--frames-dir for PNG frames")
    finally:
        vw.release()
        if os.path.exists(probe):
            os.unlink(probe)


def write_video(path, frames, fps: float = 30.0) -> str:
    """Encode 8-bit RGB `frames` (all one size) with OpenCV's VideoWriter; the file appears whole
    (a temporary name in the same folder, then a rename) or not at all."""
    import cv2

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FOURCC:
        raise ValueError(f"{path}: unknown video extension {ext or '(none)'!r} (use {', '.join(FOURCC)})")
    if not frames:
        raise ValueError(f"{path}: no frames to write")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be a positive number, got {fps}")
    h, w = frames[0].shape[:2]
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"{path}: folder {folder} does not exist")
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{os.path.basename(path)}")
    vw = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*FOURCC[ext]), float(fps), (w, h))
    try:
        if not vw.isOpened():
            raise OSError(f"{path}: OpenCV's VideoWriter cannot encode {ext} ({FOURCC[ext]}) here "
                          f"(OpenCV {cv2.__version__} without that codec); try another extension, or "
                          "--frames-dir for PNG frames")
        for i, f in enumerate(frames):
            if f.shape[:2] != (h, w):
                raise ValueError(f"{path}: frame {i} is {f.shape[1]}x{f.shape[0]}, the first is {w}x{h}")
            vw.write(np.ascontiguousarray(f[..., ::-1]))
        vw.release()
        if not os.path.isfile(tmp) or os.path.getsize(tmp) == 0:
            raise OSError(f"{path}: OpenCV wrote no video data")
        got = _count_frames(tmp)  # VideoWriter does not report a write the OS refused (a full disk)
        if got is None:  # unreadable: truncated by the OS, or a build whose reader lacks this container
            raise OSError(f"{path}: OpenCV cannot read back the video it wrote (is the disk full? else this "
                          f"OpenCV build reads no {ext}: try another extension, or --frames-dir)")
        if got != len(frames):
            raise OSError(f"{path}: the video was not written whole ({got} of {len(frames)} frames read back; "
                          "is the disk full?)")
        os.replace(tmp, path)
    except BaseException:
        vw.release()
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _count_frames(path: str) -> int:
    """The frames OpenCV can read back from a video file (demuxed, not decoded), or None when this
    OpenCV build cannot open the container it wrote (its reader and writer backends differ)."""
    import cv2

    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        cap.release()
        return None
    n = 0
    try:
        while cap.isOpened() and cap.grab():
            n += 1
    finally:
        cap.release()
    return n


def read_video(path) -> list:
    """The frames of a video file as 8-bit RGB arrays (tests, checks)."""
    import cv2

    cap = cv2.VideoCapture(os.fspath(path))
    if not cap.isOpened():
        raise OSError(f"{path}: OpenCV cannot open this video")
    out = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        out.append(f[..., ::-1])
    cap.release()
    return out
