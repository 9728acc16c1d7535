"""nerfstudio `transforms.json` (issue 13): detected as its own kind (not a Blender scene), the LLFF
protocol, intrinsics scaled with the images, OpenCV distortion undone (checked against
cv2.projectPoints of the distorted camera), fisheye refused by name."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import reings
from reings.data.loader import detect_format
from reings.data.types import SceneError

cv2 = pytest.importorskip("cv2")

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _write(folder, n=10, w=80, h=60, dist=None, model="OPENCV", per_frame=False, dots=None):
    os.makedirs(folder / "images", exist_ok=True)
    rng = np.random.default_rng(0)
    meta = {"camera_model": model, "fl_x": 70.0, "fl_y": 72.0, "cx": 41.0, "cy": 29.5, "w": w, "h": h, "frames": []}
    for k, v in (dist or {}).items():
        meta[k] = v
    for i in range(n):
        im = dots if dots is not None else rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / "images" / f"frame_{i:05d}.png"), im)
        c2w_cv = np.eye(4)
        c2w_cv[:3, 3] = [0.1 * i, 0.0, 0.0]
        fr = {"file_path": f"images/frame_{i:05d}.png", "transform_matrix": (c2w_cv @ GL_TO_CV).tolist()}
        if per_frame:
            fr.update({k: meta.pop(k) for k in ("fl_x", "fl_y", "cx", "cy") if k in meta} if i == 0 else {})
        meta["frames"].append(fr)
    (folder / "transforms.json").write_text(json.dumps(meta))


def test_detected_loaded_and_split_like_llff(tmp_path):
    _write(tmp_path)
    assert detect_format(str(tmp_path)) == "nerfstudio"
    sc = reings.load_scene(str(tmp_path), factor=1)
    assert sc.kind == "nerfstudio" and len(sc) == 10 and sc.names[0] == "images/frame_00000.png"
    cam = sc.cameras[3]
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (70.0, 72.0, 41.0, 29.5)
    np.testing.assert_allclose(cam.center, [0.3, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cam.viewmat[:3, :3], np.eye(3), atol=1e-12)  # GL -> CV axes undone
    tr, te = reings.few_shot_split(sc, 3)
    assert te == [0, 8] and len(tr) == 3  # the LLFF rule: every 8th held out
    half = reings.load_scene(str(tmp_path), factor=2)
    assert half.images[0].shape == (30, 40, 3) and half.cameras[0].fx == pytest.approx(35.0)


def test_a_blender_style_single_file_stays_blender(tmp_path):
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": []}))
    assert detect_format(str(tmp_path)) == "blender"


def test_opencv_distortion_is_undone(tmp_path):
    """A dot imaged through the distorted camera lands, after loading, where the returned pinhole
    camera projects its 3D point."""
    w, h = 160, 120
    K = np.array([[140.0, 0, 80.0], [0, 140.0, 60.0], [0, 0, 1]])
    dist = {"k1": -0.25, "k2": 0.05, "p1": 0.001, "p2": -0.002}
    D = np.array([dist["k1"], dist["k2"], dist["p1"], dist["p2"], 0.0])
    X = np.array([[0.35, -0.2, 1.0]])  # a 3D point in the camera frame
    Kcv = K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])  # OpenCV: pixel centres at integers
    uv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), Kcv, D)
    u, v = uv[0, 0]
    img = np.zeros((h, w, 3), np.uint8)
    cv2.circle(img, (int(round(u * 16)), int(round(v * 16))), 32, (255, 255, 255), -1, cv2.LINE_AA, shift=4)
    meta_dir = tmp_path / "s"
    _write(meta_dir, n=2, w=w, h=h, dots=img)
    m = json.loads((meta_dir / "transforms.json").read_text())
    m.update({"fl_x": 140.0, "fl_y": 140.0, "cx": 80.0, "cy": 60.0, **dist})
    (meta_dir / "transforms.json").write_text(json.dumps(m))
    sc = reings.load_scene(str(meta_dir), factor=1)
    cam = sc.cameras[0]
    p = cam.K @ X[0]
    want = p[:2] / p[2] - 0.5  # pixel centres at +0.5
    g = sc.images[0].mean(-1)
    ys, xs = np.nonzero(g > 0.5 * g.max())
    got = np.array([xs.mean(), ys.mean()])
    assert np.linalg.norm(got - want) < 0.15, (got, want)  # 0.21 px with the half-pixel convention ignored
    assert not np.allclose(cam.K, K)  # the new pinhole keeps only valid pixels


def test_unsupported_models_are_named(tmp_path):
    _write(tmp_path / "a", model="OPENCV_FISHEYE")
    with pytest.raises(SceneError, match="OPENCV_FISHEYE is not supported"):
        reings.load_scene(str(tmp_path / "a"))
    _write(tmp_path / "b", dist={"k4": 0.1})
    with pytest.raises(SceneError, match="k4"):
        reings.load_scene(str(tmp_path / "b"))
