"""Bad input gives a `SceneError` (a ValueError) naming the file and the problem."""
from __future__ import annotations

import os

import numpy as np
import pytest

from reings import Camera
from reings.data import SceneError, load_scene
from reings.data.procedural import look_at

pytest.importorskip("cv2")
from reings.data.images import read_image, write_png  # noqa: E402


def _llff(tmp_path, n_img=2, n_pose=2, nan=False, w=16, h=12):
    os.makedirs(tmp_path / "images_8", exist_ok=True)
    for i in range(n_img):
        write_png(str(tmp_path / "images_8" / f"image{i:03d}.png"), np.full((h, w, 3), 0.5, np.float32))
    rows = []
    for i in range(n_pose):
        c2w = np.linalg.inv(look_at([0.2 * i, 0, -5], [0, 0, 0]))
        R = c2w[:3, :3]
        cols = np.stack([R[:, 1], R[:, 0], -R[:, 2], c2w[:3, 3], [h * 8, w * 8, 100.0]], 1)
        rows.append(np.concatenate([cols.ravel(), [1, 10]]))
    pb = np.stack(rows)
    if nan:
        pb[1, 3] = np.nan
    np.save(tmp_path / "poses_bounds.npy", pb)
    return tmp_path


def test_missing_folder(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_scene(str(tmp_path / "nope"))
    with pytest.raises(SceneError, match="cannot detect"):
        load_scene(str(tmp_path))  # empty folder


def test_unknown_dataset(tmp_path):
    with pytest.raises(SceneError, match="unknown dataset"):
        load_scene(str(tmp_path), dataset="kitti")


def test_pose_image_count_mismatch(tmp_path):
    _llff(tmp_path, n_img=3, n_pose=2)
    with pytest.raises(SceneError, match=r"poses_bounds.npy: 2 poses but 3 images"):
        load_scene(str(tmp_path))


def test_nan_pose(tmp_path):
    _llff(tmp_path, nan=True)
    with pytest.raises(SceneError, match=r"poses_bounds.npy row 1 \(image001.png\): non-finite"):
        load_scene(str(tmp_path))


def test_bad_poses_bounds_shape(tmp_path):
    _llff(tmp_path)
    np.save(tmp_path / "poses_bounds.npy", np.zeros((2, 15)))
    with pytest.raises(SceneError, match=r"expected shape \(N, 17\)"):
        load_scene(str(tmp_path), dataset="llff")


def test_missing_image_folder(tmp_path):
    _llff(tmp_path)
    import shutil

    shutil.rmtree(tmp_path / "images_8")
    with pytest.raises(SceneError, match="images"):
        load_scene(str(tmp_path))


def test_truncated_png(tmp_path):
    _llff(tmp_path)
    p = tmp_path / "images_8" / "image001.png"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(SceneError, match=r"image001.png: truncated PNG"):
        load_scene(str(tmp_path))


def test_corrupt_images(tmp_path):
    p = tmp_path / "x.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10 + b"\x00\x00\x00\x00IEND\xaeB`\x82")
    with pytest.raises(SceneError, match="x.png: cannot decode"):
        read_image(str(p))
    j = tmp_path / "y.jpg"
    import cv2

    ok, buf = cv2.imencode(".jpg", np.full((8, 8, 3), 128, np.uint8))
    j.write_bytes(buf.tobytes()[:-40])
    with pytest.raises(SceneError, match="y.jpg: truncated JPEG"):
        read_image(str(j))
    (tmp_path / "z.png").write_bytes(b"")
    with pytest.raises(SceneError, match="empty"):
        read_image(str(tmp_path / "z.png"))


@pytest.mark.parametrize("model,params", [("SIMPLE_RADIAL", [20, 8, 6, 0.05]), ("OPENCV_FISHEYE", [20, 20, 8, 6, 0, 0, 0, 0])])
def test_unsupported_camera_model(tmp_path, model, params):
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=16, height=12, params=params, camera_id=1))
    rec.add_image_with_trivial_frame(pycolmap.Image(name="a.png", camera_id=1, image_id=1),
                                     pycolmap.Rigid3d(np.eye(4)[:3]))
    os.makedirs(tmp_path / "sparse" / "0")
    rec.write(str(tmp_path / "sparse" / "0"))
    os.makedirs(tmp_path / "images")
    write_png(str(tmp_path / "images" / "a.png"), np.zeros((12, 16, 3)))
    with pytest.raises(SceneError, match=f"unsupported camera model {model}"):
        load_scene(str(tmp_path), factor=1)
    if model == "SIMPLE_RADIAL":  # a user may accept LLFF-style small distortion explicitly
        sc = load_scene(str(tmp_path), factor=1, ignore_distortion=True)
        assert sc.cameras[0].fx == 20


def test_colmap_missing_image_file(tmp_path):
    pytest.importorskip("pycolmap")
    from reings.data.colmap import write_model

    K = np.array([[20, 0, 8], [0, 20, 6], [0, 0, 1.0]])
    write_model(str(tmp_path / "sparse" / "0"), [Camera(K, np.eye(4), 16, 12)], ["gone.png"])
    os.makedirs(tmp_path / "images")
    with pytest.raises(SceneError, match="gone.png"):
        load_scene(str(tmp_path), factor=1)


def test_dtu_bad_npz(tmp_path):
    os.makedirs(tmp_path / "image")
    write_png(str(tmp_path / "image" / "000.png"), np.zeros((30, 40, 3)))
    P = np.eye(4)
    P[0, 0] = np.nan
    np.savez(tmp_path / "cameras_sphere.npz", world_mat_0=P)
    with pytest.raises(SceneError, match=r"cameras_sphere.npz \(world_mat_0, 000.png\): non-finite"):
        load_scene(str(tmp_path))
    np.savez(tmp_path / "cameras_sphere.npz", world_mat_0=np.eye(4), world_mat_1=np.eye(4))
    with pytest.raises(SceneError, match="2 cameras but 1 images"):
        load_scene(str(tmp_path))


def test_blender_bad_json(tmp_path):
    (tmp_path / "transforms_train.json").write_text("{not json")
    with pytest.raises(SceneError, match="transforms_train.json: invalid JSON"):
        load_scene(str(tmp_path))
    (tmp_path / "transforms_train.json").write_text('{"camera_angle_x": 0.7, "frames": [{"file_path": "./r_0", '
                                                    '"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,NaN],[0,0,0,1]]}]}')
    with pytest.raises(SceneError, match="frame 0: non-finite"):
        load_scene(str(tmp_path))


def test_scene_error_is_value_error():
    assert issubclass(SceneError, ValueError)


@pytest.mark.parametrize("convert", [lambda a: a.astype(np.complex128) + 1e-3j, lambda a: a.astype(str),
                                     lambda a: a > 0])
def test_poses_bounds_must_be_real(tmp_path, convert):
    """Issue 14 item 10: a complex poses_bounds.npy was accepted with only a numpy warning (its
    imaginary part dropped); strings and booleans are refused too, naming the file and dtype."""
    import warnings

    _llff(tmp_path)
    pb = np.load(tmp_path / "poses_bounds.npy")
    np.save(tmp_path / "poses_bounds.npy", convert(pb))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(SceneError, match=r"poses_bounds.npy: expected real numbers, got an array of dtype"):
            load_scene(str(tmp_path))


@pytest.mark.parametrize("bad, needle", [(np.array([None, 1], dtype=object), "cannot read"),
                                         (np.eye(3), "expected a 4x4 (or 3x4) matrix, got shape (3, 3)"),
                                         (np.full((4, 4), "a"), "expected real numbers"),
                                         (np.eye(4) * 1j, "expected real numbers")])
def test_dtu_camera_entries_name_the_file(tmp_path, bad, needle):
    """Issue 14 item 16: a cameras_sphere.npz with an object array, strings or a world_mat of the
    wrong shape gave messages (or an IndexError) that did not name the file."""
    import re

    from reings.data.images import write_png

    (tmp_path / "image").mkdir()
    for i in range(2):
        write_png(str(tmp_path / "image" / f"{i:06d}.png"), np.full((30, 40, 3), 0.5, np.float32))
    np.savez(tmp_path / "cameras_sphere.npz", world_mat_0=bad, world_mat_1=np.eye(4))
    with pytest.raises(SceneError, match=r"cameras_sphere.npz \(world_mat_0, 000000.png\): " + re.escape(needle)):
        load_scene(str(tmp_path))
