"""cameras.json (reings.io.cameras): the 3DGS (Inria) layout, written and read back exactly, and
bad files refused with the file and the entry named."""
from __future__ import annotations

import json

import numpy as np
import pytest

from reings.io.cameras import CamerasFileError, camera_entry, read_cameras_json, write_cameras_json
from reings.types import Camera


def _rot(axis, deg):
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _camera(seed=0, w=64, h=48):
    rng = np.random.default_rng(seed)
    R = _rot(0, rng.uniform(-40, 40)) @ _rot(1, rng.uniform(-40, 40)) @ _rot(2, rng.uniform(-10, 10))
    V = np.eye(4)
    V[:3, :3], V[:3, 3] = R, rng.normal(size=3)
    K = np.array([[50.0 + seed, 0, 31.5], [0, 52.0, 24.25], [0, 0, 1]])
    return Camera(K, V, w, h)


def test_entry_is_the_3dgs_layout():
    """position = camera centre, rotation = camera-to-world (its columns are the camera axes in
    world coordinates), as 3DGS's camera_to_JSON writes them."""
    cam = _camera(1)
    e = camera_entry(7, "sub/img_0001.JPG", cam, "train")
    assert e["id"] == 7 and e["img_name"] == "img_0001" and (e["width"], e["height"]) == (64, 48)
    C = np.array(e["position"])
    R = np.array(e["rotation"])
    np.testing.assert_allclose(cam.viewmat[:3, :3] @ C + cam.viewmat[:3, 3], 0, atol=1e-12)
    fwd_world = R @ np.array([0, 0, 1.0])  # the camera's z axis in world coordinates
    np.testing.assert_allclose(fwd_world, cam.viewmat[2, :3], atol=1e-12)
    assert (e["fx"], e["fy"], e["cx"], e["cy"]) == (51.0, 52.0, 31.5, 24.25)


def test_round_trip(tmp_path):
    cams = [_camera(i) for i in range(4)]
    p = tmp_path / "cameras.json"
    write_cameras_json(p, [("train", ["a.png", "b.png"], cams[:2]), ("test", ["c.png", "d.png"], cams[2:])])
    recs = read_cameras_json(p)
    assert [r.name for r in recs] == ["a", "b", "c", "d"] and [r.split for r in recs] == ["train"] * 2 + ["test"] * 2
    for r, c in zip(recs, cams):
        np.testing.assert_allclose(r.camera.viewmat, c.viewmat, atol=1e-12)
        np.testing.assert_array_equal(r.camera.K, c.K)
        assert (r.camera.width, r.camera.height) == (c.width, c.height)
    assert [r.name for r in read_cameras_json(p, split="test")] == ["c", "d"]
    assert [e["id"] for e in json.loads(p.read_text())] == [0, 1, 2, 3]


def test_a_3dgs_file_without_principal_point_means_the_image_centre(tmp_path):
    e = camera_entry(0, "x", _camera(2), "train")
    for k in ("cx", "cy", "split"):
        del e[k]
    p = tmp_path / "c.json"
    p.write_text(json.dumps([e]))
    (r,) = read_cameras_json(p)
    assert (r.camera.cx, r.camera.cy, r.split) == (32.0, 24.0, "")


@pytest.mark.parametrize("edit, msg", [
    (lambda e: e.pop("fx"), "lacks 'fx'"),
    (lambda e: e.update(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "not a proper rotation"),
    (lambda e: e.update(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "not a proper rotation"),
    (lambda e: e.update(position=[0, 0]), "'position' must be finite numbers of shape"),
    (lambda e: e.update(fx=float("nan")), "'fx' must be a finite number"),
    (lambda e: e.update(fy=-3.0), "focal lengths must be positive"),
    (lambda e: e.update(width=0), "positive integers"),
    (lambda e: e.update(height="48"), "positive integers"),
])
def test_bad_entries_name_the_file_and_the_camera(tmp_path, edit, msg):
    good = camera_entry(0, "a", _camera(0), "train")
    bad = camera_entry(1, "b", _camera(1), "train")
    edit(bad)
    p = tmp_path / "cams.json"
    p.write_text(json.dumps([good, bad]))
    with pytest.raises(CamerasFileError, match=msg) as ei:
        read_cameras_json(p)
    assert str(p) in str(ei.value) and "camera 1" in str(ei.value)


def test_unreadable_files(tmp_path):
    p = tmp_path / "c.json"
    p.write_text("{not json")
    with pytest.raises(CamerasFileError, match="not a JSON file"):
        read_cameras_json(p)
    p.write_text("[]")
    with pytest.raises(CamerasFileError, match="non-empty JSON list"):
        read_cameras_json(p)
    with pytest.raises(FileNotFoundError, match="cameras file not found"):
        read_cameras_json(tmp_path / "none.json")
    p.write_text(json.dumps([camera_entry(0, "a", _camera(0), "train")]))
    with pytest.raises(CamerasFileError, match="no camera of split 'test'"):
        read_cameras_json(p, split="test")
