"""COLMAP models through pycolmap: the only module that imports `pycolmap`.

Owns:
* reading a COLMAP model (binary or text, any COLMAP version pycolmap reads) into cameras,
  world-to-camera poses and sparse points (`read_model`, `load_colmap_scene`);
* partial models as shipped with the LLFF release (`cameras.bin` + `points3D.bin`, no
  `images.bin`): pycolmap cannot load a model without its images, so the cameras are read by
  pycolmap from a temporary copy with empty image/point files, and `points3D` (which only needs
  xyz and colour here) by `_read_points3d_file`, the one small hand-written parser, documented
  as such (`read_partial_model`);
* building a `pycolmap.Reconstruction` from known cameras (`reconstruction_from_cameras`;
  tests write tiny models with it) and the feature extraction / matching / known-pose
  triangulation steps that `sfm.py` orchestrates (`triangulate_known_poses`).

COLMAP's camera frame is OpenCV's (x right, y down, z forward) and its pixel centres are at
+0.5, the same conventions as `reings.Camera`, so cam_from_world is the viewmat unchanged.
"""
from __future__ import annotations

import os
import shutil
import struct
import tempfile

import numpy as np

from ..types import Camera
from .types import Scene, SceneError, make_camera

# models whose geometry is a pinhole; the others carry distortion or non-pinhole projection
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
# models whose extra (distortion) parameters may be zero, making them pinholes in practice
RADIAL_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")


def _pycolmap():
    try:
        import pycolmap
    except ImportError as e:  # pragma: no cover
        raise SceneError("COLMAP models need pycolmap: pip install 'reings[data]' (pycolmap)") from e
    return pycolmap


def find_model_dir(path: str) -> str | None:
    """The folder holding cameras.{bin,txt}: `path/sparse/0`, `path/sparse`, or `path` itself."""
    for sub in (os.path.join("sparse", "0"), "sparse", ""):
        d = os.path.join(path, sub) if sub else path
        if any(os.path.isfile(os.path.join(d, f)) for f in ("cameras.bin", "cameras.txt")):
            return d
    return None


def _model_ext(d: str) -> str:
    return ".bin" if os.path.isfile(os.path.join(d, "cameras.bin")) else ".txt"


def read_model(model_dir: str):
    """A `pycolmap.Reconstruction` read from `model_dir` (binary or text); `SceneError` if it cannot."""
    pycolmap = _pycolmap()
    if not os.path.isdir(model_dir):
        raise SceneError(f"{model_dir}: COLMAP model folder not found")
    ext = _model_ext(model_dir)
    for f in ("cameras", "images", "points3D"):
        if not os.path.isfile(os.path.join(model_dir, f + ext)):
            raise SceneError(f"{os.path.join(model_dir, f + ext)}: file not found (incomplete COLMAP model)")
    try:
        return pycolmap.Reconstruction(model_dir)
    except Exception as e:  # pycolmap raises ValueError/RuntimeError with its own text
        raise SceneError(f"{model_dir}: cannot read COLMAP model: {e}") from e


def camera_K(cam, where: str, ignore_distortion: bool = False) -> tuple[np.ndarray, int, int]:
    """(K [3, 3], width, height) of a pycolmap camera; non-pinhole models are a `SceneError`."""
    model = cam.model_name if hasattr(cam, "model_name") else str(cam.model).split(".")[-1]
    params = np.asarray(cam.params, dtype=np.float64)
    if model not in PINHOLE_MODELS:
        extra = params[list(cam.extra_params_idxs())] if hasattr(cam, "extra_params_idxs") else params[3:]
        if model not in RADIAL_MODELS or (np.any(np.abs(extra) > 1e-9) and not ignore_distortion):
            raise SceneError(
                f"{where}: unsupported camera model {model} (params {params.tolist()}): "
                "reings needs undistorted pinhole images (SIMPLE_PINHOLE/PINHOLE); run COLMAP's "
                "image_undistorter first"
                + ("" if model not in RADIAL_MODELS else ", or pass ignore_distortion=True")
            )
    K = np.asarray(cam.calibration_matrix(), dtype=np.float64)
    return K, int(cam.width), int(cam.height)


def _read_points3d_file(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz [P, 3] float64, rgb [P, 3] uint8, error [P] float64) from points3D.bin or .txt.

    Hand-written on purpose and only for partial models (no images.bin), which pycolmap refuses
    to read because their tracks name images it does not have. Track contents are skipped.
    """
    xyz, rgb, err = [], [], []
    try:
        if path.endswith(".txt"):
            with open(path) as f:
                for line in f:
                    s = line.strip()
                    if not s or s.startswith("#"):
                        continue
                    t = s.split()
                    xyz.append([float(v) for v in t[1:4]])
                    rgb.append([int(v) for v in t[4:7]])
                    err.append(float(t[7]))
        else:
            with open(path, "rb") as f:
                data = f.read()
            (n,) = struct.unpack_from("<Q", data, 0)
            off = 8
            rec = struct.Struct("<Q3d3BdQ")  # id, xyz, rgb, error, track length (43 bytes)
            for _ in range(n):
                pid, x, y, z, r, g, b, e, tl = rec.unpack_from(data, off)
                off += rec.size + 8 * tl  # track: tl x (uint32 image_id, uint32 point2D_idx)
                xyz.append((x, y, z))
                rgb.append((r, g, b))
                err.append(e)
            if off != len(data):
                raise SceneError(f"{path}: {len(data) - off} trailing bytes after {n} points (corrupt file)")
    except (struct.error, ValueError, IndexError) as e:
        raise SceneError(f"{path}: truncated or corrupt points3D file ({e})") from e
    return (
        np.asarray(xyz, dtype=np.float64).reshape(-1, 3),
        np.asarray(rgb, dtype=np.uint8).reshape(-1, 3),
        np.asarray(err, dtype=np.float64),
    )


def read_partial_model(model_dir: str) -> tuple[dict, np.ndarray, np.ndarray]:
    """({camera_id: pycolmap.Camera}, xyz [P, 3], rgb [P, 3] uint8) from a model that may lack images.

    Cameras go through pycolmap: the cameras file is copied into a temporary folder next to empty
    images/points3D files, which pycolmap reads as a legacy model with no images.
    """
    pycolmap = _pycolmap()
    ext = _model_ext(model_dir)
    cam_file = os.path.join(model_dir, "cameras" + ext)
    if not os.path.isfile(cam_file):
        raise SceneError(f"{cam_file}: file not found")
    with tempfile.TemporaryDirectory(prefix="reings_colmap_") as tmp:
        shutil.copy(cam_file, tmp)
        for f in ("images", "points3D"):
            if ext == ".bin":
                with open(os.path.join(tmp, f + ext), "wb") as fh:
                    fh.write(struct.pack("<Q", 0))
            else:
                open(os.path.join(tmp, f + ext), "w").close()
        try:
            rec = pycolmap.Reconstruction(tmp)
        except Exception as e:
            raise SceneError(f"{cam_file}: cannot read COLMAP cameras: {e}") from e
        cameras = {int(k): v for k, v in rec.cameras.items()}
    pts_file = os.path.join(model_dir, "points3D" + ext)
    if os.path.isfile(pts_file):
        xyz, rgb, _ = _read_points3d_file(pts_file)
    else:
        xyz, rgb = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    return cameras, xyz, rgb


def read_points(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(xyz [P, 3] float64, rgb [P, 3] float32 in [0, 1]) of the sparse model under scene folder `path`.

    Uses pycolmap for a complete model, the partial reader otherwise. Empty arrays if no model.
    """
    d = find_model_dir(path)
    if d is None:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    ext = _model_ext(d)
    if os.path.isfile(os.path.join(d, "images" + ext)):
        rec = read_model(d)
        pts = [p for _, p in sorted(rec.points3D.items())]
        xyz = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
        rgb = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    else:
        _, xyz, rgb = read_partial_model(d)
    return xyz, rgb.astype(np.float32) / 255.0


def load_colmap_scene(path: str, factor: int = 8, ignore_distortion: bool = False, images: str | None = None) -> Scene:
    """A COLMAP scene folder (`images/` + `sparse/0/`, binary or text) as a `Scene`, sorted by name.

    Images come from `images_{factor}/` if it exists, else `images/` resized to
    round(W/factor) x round(H/factor) (3DGS `-r factor`). Intrinsics are scaled by the actual
    size ratio. Points are the model's (built from all views: `points_from_all_views=True`).
    """
    from . import images as imgs

    model_dir = find_model_dir(path)
    if model_dir is None:
        raise SceneError(f"{path}: no COLMAP model (sparse/0/cameras.bin or .txt)")
    rec = read_model(model_dir)
    img_dir, extra = (images, 1.0) if images else imgs.factor_image_folder(path, factor)
    entries = sorted(rec.images.values(), key=lambda im: im.name)
    if not entries:
        raise SceneError(f"{model_dir}: COLMAP model has no images")
    ims, cams, names = [], [], []
    for im in entries:
        where = f"{model_dir} (image {im.name})"
        K, w0, h0 = camera_K(rec.cameras[im.camera_id], where, ignore_distortion)
        cfw = im.cam_from_world
        cfw = cfw() if callable(cfw) else cfw
        V = np.eye(4)
        V[:3, :4] = np.asarray(cfw.matrix(), dtype=np.float64)
        fpath = os.path.join(img_dir, im.name)
        if not os.path.isfile(fpath):
            raise SceneError(f"{fpath}: image named in {model_dir} not found")
        rgb = imgs.read_image(fpath)
        h1, w1 = rgb.shape[:2]
        if extra != 1.0:
            w1, h1 = max(1, round(w1 * extra)), max(1, round(h1 * extra))
            rgb = imgs.resize(rgb, w1, h1)
        K = K.copy()
        K[0] *= w1 / w0
        K[1] *= h1 / h0
        ims.append(rgb)
        cams.append(make_camera(K, V, w1, h1, where))
        names.append(im.name)
    pts = [p for _, p in sorted(rec.points3D.items())]
    xyz = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], dtype=np.float32).reshape(-1, 3) / 255.0
    return Scene(ims, cams, names, kind="colmap", points=xyz, point_colors=rgb,
                 points_from_all_views=True, source=path, meta={"factor": factor})


def reconstruction_from_cameras(cameras: list[Camera], names: list[str], image_ids=None, camera_ids=None):
    """A `pycolmap.Reconstruction` with one PINHOLE camera and one posed image per view, no points."""
    pycolmap = _pycolmap()
    rec = pycolmap.Reconstruction()
    n = len(cameras)
    image_ids = list(range(1, n + 1)) if image_ids is None else [int(i) for i in image_ids]
    camera_ids = list(range(1, n + 1)) if camera_ids is None else [int(i) for i in camera_ids]
    for cam, name, iid, cid in zip(cameras, names, image_ids, camera_ids):
        if not rec.exists_camera(cid):
            pc = pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                                 params=[cam.fx, cam.fy, cam.cx, cam.cy], camera_id=cid)
            rec.add_camera_with_trivial_rig(pc)
        img = pycolmap.Image(name=name, camera_id=cid, image_id=iid)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.asarray(cam.viewmat[:3, :4], dtype=np.float64)))
    return rec


def write_model(out_dir: str, cameras: list[Camera], names: list[str], points=None, colors=None, text=False) -> None:
    """Write a COLMAP model of known cameras (+ optional points without tracks) through pycolmap."""
    pycolmap = _pycolmap()
    rec = reconstruction_from_cameras(cameras, names)
    if points is not None:
        cols = np.zeros((len(points), 3), np.uint8) if colors is None else np.asarray(colors)
        for p, c in zip(np.asarray(points, np.float64), cols):
            rec.add_point3D(p, pycolmap.Track(), np.asarray(c, dtype=np.uint8))
    os.makedirs(out_dir, exist_ok=True)
    (rec.write_text if text else rec.write)(out_dir)


def triangulate_known_poses(image_dir: str, names: list[str], cameras: list[Camera], work_dir: str,
                            max_features: int = 8192, max_reproj_error: float = 4.0,
                            min_tri_angle: float = 1.5, num_threads: int = -1, peak_threshold: float | None = None,
                            guided_matching: bool = True, verbose: bool = False) -> dict:
    """SIFT features, exhaustive matching, and triangulation with the given (fixed) poses and intrinsics.

    The COLMAP `point_triangulator` flow (as FSGS `tools/colmap_llff.py`), run through pycolmap on
    the CPU: `extract_features` with one PINHOLE camera per image set to the known intrinsics,
    `match_exhaustive` (geometric verification included), then `triangulate_points` on a
    reconstruction whose images carry the known poses, with intrinsics and poses not refined.

    Returns {"xyz": [P, 3] float64, "rgb": [P, 3] float32, "error": [P], "track_length": [P],
    "num_matched_pairs": int}.
    """
    pycolmap = _pycolmap()
    old_level = pycolmap.logging.minloglevel
    if not verbose:
        pycolmap.logging.minloglevel = 2  # glog ERROR: COLMAP logs every step at INFO
    try:
        return _triangulate_known_poses(pycolmap, image_dir, names, cameras, work_dir, max_features,
                                        max_reproj_error, min_tri_angle, num_threads, peak_threshold,
                                        guided_matching)
    finally:
        pycolmap.logging.minloglevel = old_level


def _triangulate_known_poses(pycolmap, image_dir, names, cameras, work_dir, max_features, max_reproj_error,
                             min_tri_angle, num_threads, peak_threshold, guided_matching) -> dict:
    db_path = os.path.join(work_dir, "database.db")
    if os.path.exists(db_path):
        os.remove(db_path)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = num_threads
    ext.use_gpu = False
    ext.sift.max_num_features = max_features
    if peak_threshold is not None:
        ext.sift.peak_threshold = float(peak_threshold)
    try:
        pycolmap.extract_features(db_path, image_dir, image_names=list(names),
                                  camera_mode=pycolmap.CameraMode.PER_IMAGE, reader_options=reader,
                                  extraction_options=ext, device=pycolmap.Device.cpu)
    except Exception as e:
        raise SceneError(f"{image_dir}: COLMAP feature extraction failed: {e}") from e
    # the database assigned ids; the reconstruction must use the same ones. The known intrinsics
    # go in before matching so that geometric verification is calibrated (essential matrix).
    db = pycolmap.Database.open(db_path)
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        for cam, name in zip(cameras, names):
            if name not in by_name:
                raise SceneError(f"{os.path.join(image_dir, name)}: COLMAP could not read the image")
            c = db.read_camera(by_name[name].camera_id)
            c.model = pycolmap.CameraModelId.PINHOLE
            c.width, c.height = cam.width, cam.height
            c.params = [cam.fx, cam.fy, cam.cx, cam.cy]
            c.has_prior_focal_length = True
            db.update_camera(c)
    finally:
        db.close()
    try:
        match = pycolmap.FeatureMatchingOptions()
        match.num_threads = num_threads
        match.use_gpu = False
        match.guided_matching = guided_matching
        pycolmap.match_exhaustive(db_path, matching_options=match, device=pycolmap.Device.cpu)
    except Exception as e:
        raise SceneError(f"{image_dir}: COLMAP feature matching failed: {e}") from e
    db = pycolmap.Database.open(db_path)
    try:
        n_pairs = int(db.num_verified_image_pairs())
    finally:
        db.close()
    rec = reconstruction_from_cameras(cameras, names,
                                      image_ids=[by_name[n].image_id for n in names],
                                      camera_ids=[by_name[n].camera_id for n in names])
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = num_threads
    opts.triangulation.ignore_two_view_tracks = False  # with 2 views every track is two-view
    opts.triangulation.min_angle = float(min_tri_angle)
    opts.triangulation.create_max_angle_error = 2.0
    opts.mapper.filter_max_reproj_error = float(max_reproj_error)
    opts.mapper.filter_min_tri_angle = float(min_tri_angle)
    out_dir = os.path.join(work_dir, "triangulated")
    os.makedirs(out_dir, exist_ok=True)
    try:
        rec = pycolmap.triangulate_points(rec, db_path, image_dir, out_dir, clear_points=True,
                                          options=opts, refine_intrinsics=False)
    except Exception as e:
        raise SceneError(f"{image_dir}: COLMAP triangulation failed: {e}") from e
    pts = [p for _, p in sorted(rec.points3D.items())]
    return {
        "xyz": np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3),
        "rgb": np.array([p.color for p in pts], dtype=np.float32).reshape(-1, 3) / 255.0,
        "error": np.array([p.error for p in pts], dtype=np.float64),
        "track_length": np.array([p.track.length() for p in pts], dtype=np.int64),
        "num_matched_pairs": n_pairs,
    }


# {{{ structure from motion of unposed photos (`reings process`)

def map_photos(image_dir: str, names: list[str], work_dir: str, single_camera: bool = True,
               max_features: int = 8192, num_threads: int = -1, step=None) -> tuple:
    """COLMAP's automatic flow on unposed photos, on the CPU: SIFT features (SIMPLE_RADIAL, one
    camera for all photos when `single_camera`), exhaustive matching with geometric verification,
    incremental mapping. `step(name)` is called before each step (progress).

    Returns (the reconstruction with the most registered images, its model folder under
    `work_dir`, {name: why not registered}). SceneError when no model can be made."""
    pycolmap = _pycolmap()
    step = step or (lambda name: None)
    db_path = os.path.join(work_dir, "database.db")
    if os.path.exists(db_path):
        os.remove(db_path)
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2
    try:
        step("features")
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "SIMPLE_RADIAL"
        ext = pycolmap.FeatureExtractionOptions()
        ext.num_threads, ext.use_gpu = num_threads, False
        ext.sift.max_num_features = max_features
        mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.AUTO
        try:
            pycolmap.extract_features(db_path, image_dir, image_names=list(names), camera_mode=mode,
                                      reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
        except Exception as e:
            raise SceneError(f"{image_dir}: COLMAP feature extraction failed: {e}") from e
        step("matching")
        match = pycolmap.FeatureMatchingOptions()
        match.num_threads, match.use_gpu = num_threads, False
        try:
            pycolmap.match_exhaustive(db_path, matching_options=match, device=pycolmap.Device.cpu)
        except Exception as e:
            raise SceneError(f"{image_dir}: COLMAP feature matching failed: {e}") from e
        feats = _feature_counts(pycolmap, db_path)
        step("mapping")
        opts = pycolmap.IncrementalPipelineOptions()
        opts.num_threads = num_threads
        opts.min_model_size = 2  # few-shot: a model of two photos is a model
        opts.mapper.init_min_num_inliers = 30
        opts.mapper.abs_pose_min_num_inliers = 15
        opts.triangulation.ignore_two_view_tracks = False
        out_dir = os.path.join(work_dir, "sparse")
        os.makedirs(out_dir, exist_ok=True)
        try:
            recs = pycolmap.incremental_mapping(db_path, image_dir, out_dir, options=opts)
        except Exception as e:
            raise SceneError(f"{image_dir}: COLMAP mapping failed: {e}") from e
    finally:
        pycolmap.logging.minloglevel = old_level
    if not recs:
        raise SceneError(f"{image_dir}: COLMAP could not register any pair of the {len(names)} photos "
                         f"(features per photo: {_fmt_counts(feats)}); photos of one scene with more overlap, "
                         "texture and sharpness are needed")
    key = max(recs, key=lambda k: recs[k].num_reg_images())
    rec = recs[key]
    registered = {rec.images[i].name for i in rec.reg_image_ids()}
    missing = {}
    for n in names:
        if n not in registered:
            f = feats.get(n, 0)
            missing[n] = (f"only {f} features" if f < 100 else
                          "not matched to the registered photos (too little overlap, or another scene)")
    return rec, os.path.join(out_dir, str(key)), missing


def _feature_counts(pycolmap, db_path) -> dict:
    db = pycolmap.Database.open(db_path)
    try:
        return {im.name: int(db.num_keypoints_for_image(im.image_id)) for im in db.read_all_images()}
    finally:
        db.close()


def _fmt_counts(feats: dict) -> str:
    return ", ".join(f"{n}: {c}" for n, c in sorted(feats.items())) or "none"


def undistort_model(model_dir: str, image_dir: str, out_dir: str, names: list[str]) -> None:
    """COLMAP's image undistorter: PINHOLE cameras and undistorted images in `out_dir`
    (`images/`, `sparse/`)."""
    pycolmap = _pycolmap()
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2
    try:
        pycolmap.undistort_images(out_dir, model_dir, image_dir, image_names=list(names))
    except Exception as e:
        raise SceneError(f"{model_dir}: COLMAP undistortion failed: {e}") from e
    finally:
        pycolmap.logging.minloglevel = old_level
# }}}
