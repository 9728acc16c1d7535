"""Loaders on tiny scenes the tests write themselves: LLFF, NeX, COLMAP (through pycolmap), DTU, Blender.

Axis conventions are checked against facts of each format (not against our own writer): a point
in front of the camera projects to the image centre with the right depth, world "right" lands
right of centre and world "up" above it.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from reings import Camera
from reings.data import Scene, load_scene
from reings.data.procedural import look_at

pytest.importorskip("cv2")
from reings.data.images import write_png  # noqa: E402

CAM_ATOL = 1e-6  # float64 round trips through text/npz: only printing precision is lost


def project(cam: Camera, X):
    Xc = cam.viewmat[:3, :3] @ np.asarray(X, float) + cam.viewmat[:3, 3]
    uv = cam.K @ Xc
    return uv[:2] / uv[2], Xc[2]


def _tiny_views(n=3, w=16, h=12, seed=0):
    rng = np.random.default_rng(seed)
    ims = [rng.random((h, w, 3)).astype(np.float32) for _ in range(n)]
    f = 14.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    cams = [Camera(K, look_at([0.3 * i - 0.3, 0.1 * i, -5.0], [0, 0, 0]), w, h) for i in range(n)]
    return ims, cams


def _write_images(folder, ims, fmt="image{:03d}.png"):
    os.makedirs(folder, exist_ok=True)
    names = []
    for i, im in enumerate(ims):
        names.append(fmt.format(i))
        write_png(os.path.join(folder, names[-1]), im)
    return names


def _llff_row(cam: Camera, H, W, f, near=1.0, far=10.0):
    R = cam.viewmat[:3, :3].T  # OpenCV c2w rotation: columns right, down, forward
    C = cam.center
    cols = np.stack([R[:, 1], R[:, 0], -R[:, 2], C, [H, W, f]], axis=1)  # [down, right, back, t, hwf]
    return np.concatenate([cols.ravel(), [near, far]])


# ---------------------------------------------------------------- LLFF

def test_llff_axis_convention(tmp_path):
    # camera at (0, 0, 5) in a y-up world, looking along -z: down = -y, right = +x, back = +z
    w, h = 32, 24
    _write_images(str(tmp_path / "images_8"), [np.zeros((h, w, 3), np.float32)])
    row = np.concatenate([np.stack([[0, -1, 0], [1, 0, 0], [0, 0, 1], [0, 0, 5], [h * 8, w * 8, 200.0]], 1).ravel(),
                          [1, 20]])
    np.save(tmp_path / "poses_bounds.npy", row[None])
    sc = load_scene(str(tmp_path))
    assert sc.kind == "llff" and len(sc) == 1
    cam = sc.cameras[0]
    np.testing.assert_allclose(cam.K, [[25, 0, 16], [0, 25, 12], [0, 0, 1]])  # f / 8, centre W/2, H/2
    uv, z = project(cam, [0, 0, 0])
    np.testing.assert_allclose(uv, [16, 12], atol=1e-9)
    assert z == pytest.approx(5.0)
    assert project(cam, [1, 0, 0])[0][0] > 16  # world +x is camera right
    assert project(cam, [0, 1, 0])[0][1] < 12  # world +y (up) is above the centre
    np.testing.assert_allclose(sc.bounds, [[1, 20]])


def test_llff_round_trip_and_resize(tmp_path):
    ims, cams = _tiny_views(n=3, w=32, h=24)
    rows = [_llff_row(c, 24 * 4, 32 * 4, c.fx * 4) for c in cams]
    np.save(tmp_path / "poses_bounds.npy", np.stack(rows))
    _write_images(str(tmp_path / "images"), ims)  # no images_2: `images/` is resized by 1/2
    sc = load_scene(str(tmp_path), factor=2)
    assert [im.shape for im in sc.images] == [(12, 16, 3)] * 3
    for c0, c in zip(cams, sc.cameras):
        np.testing.assert_allclose(c.viewmat, c0.viewmat, atol=CAM_ATOL)
        np.testing.assert_allclose(c.K[:2], c0.K[:2] / 2, atol=CAM_ATOL)
    # area resize by 2 averages 2x2 blocks
    ref = ims[1].reshape(12, 2, 16, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(sc.images[1], ref, atol=1 / 255 + 1e-6)


def test_nex_principal_point(tmp_path):
    ims, cams = _tiny_views(n=2, w=40, h=30)
    rows = [_llff_row(c, 30, 40, 0)[:15].reshape(3, 5)[:, :4].ravel() for c in cams]
    pb = np.concatenate([np.stack(rows), np.tile([[0.5, 30.0]], (2, 1))], axis=1)  # N x 14
    np.save(tmp_path / "poses_bounds.npy", pb)
    np.save(tmp_path / "hwf_cxcy.npy", np.array([[30], [40], [33.0], [34.0], [21.5], [13.25]]))
    _write_images(str(tmp_path / "images"), ims, "img{:03d}.png")
    sc = load_scene(str(tmp_path), factor=4)  # factor 4 = the stored size
    assert sc.kind == "llff_nex"
    np.testing.assert_allclose(sc.cameras[0].K, [[33, 0, 21.5], [0, 34, 13.25], [0, 0, 1]])
    np.testing.assert_allclose(sc.cameras[1].viewmat, cams[1].viewmat, atol=CAM_ATOL)
    sc8 = load_scene(str(tmp_path))  # factor 8: half the stored size, intrinsics halved
    assert sc8.images[0].shape == (15, 20, 3)
    np.testing.assert_allclose(sc8.cameras[0].K[:2], np.array([[33, 0, 21.5], [0, 34, 13.25]]) / 2)


# ---------------------------------------------------------------- COLMAP

@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
def test_colmap_round_trip(tmp_path, text):
    pytest.importorskip("pycolmap")
    from reings.data.colmap import write_model

    ims, cams = _tiny_views(n=3)
    names = _write_images(str(tmp_path / "images"), ims, "c{:02d}.png")
    pts = np.array([[0, 0, 0], [0.5, -0.2, 0.3]])
    write_model(str(tmp_path / "sparse" / "0"), cams[::-1], names[::-1], points=pts,
                colors=[[255, 0, 0], [0, 255, 0]], text=text)
    sc = load_scene(str(tmp_path), factor=1)
    assert sc.kind == "colmap" and sc.names == names  # sorted by name, whatever the model order
    for c0, c in zip(cams, sc.cameras):
        np.testing.assert_allclose(c.K, c0.K, atol=CAM_ATOL)
        np.testing.assert_allclose(c.viewmat, c0.viewmat, atol=CAM_ATOL)
    np.testing.assert_allclose(sc.points, pts, atol=CAM_ATOL)
    np.testing.assert_allclose(sc.point_colors[0], [1, 0, 0])
    assert sc.points_from_all_views


def test_colmap_partial_model_points(tmp_path):
    """LLFF-release models have cameras.bin + points3D.bin but no images.bin."""
    pytest.importorskip("pycolmap")
    from reings.data.colmap import read_partial_model, write_model

    ims, cams = _tiny_views(n=2)
    d = str(tmp_path / "m")
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(7, 3))
    write_model(d, cams, ["a.png", "b.png"], points=pts)
    os.remove(os.path.join(d, "images.bin"))
    cameras, xyz, rgb = read_partial_model(d)
    assert len(cameras) == 2 and xyz.shape == (7, 3)
    np.testing.assert_allclose(np.sort(xyz, axis=0), np.sort(pts, axis=0))


# ---------------------------------------------------------------- DTU

def _rot(ax, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (0, 2), (0, 1)][ax]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def test_dtu_decompose_and_scale_mat(tmp_path):
    from reings.data.dtu import decompose_projection

    rng = np.random.default_rng(3)
    n, W, H = 3, 40, 30
    scale = np.diag([200.0, 200.0, 200.0, 1.0])
    scale[:3, 3] = [10, -5, 600]  # unit sphere -> DTU mm
    K0 = np.array([[2892.3, 0.5, 823.2], [0, 2883.2, 619.1], [0, 0, 1]])
    data, Rs, Cs = {}, [], []
    for i in range(n):
        R = _rot(0, rng.uniform(-0.3, 0.3)) @ _rot(1, rng.uniform(-0.5, 0.5))
        C = scale[:3, 3] + R.T @ np.array([0, 0, -700.0])  # 700 mm in front of the object centre
        P = np.eye(4)
        P[:3, :4] = K0 @ np.concatenate([R, (-R @ C)[:, None]], 1) * rng.uniform(0.5, 2.0)  # any scale
        data[f"world_mat_{i}"], data[f"scale_mat_{i}"] = P, scale
        Rs.append(R)
        Cs.append(C)
        K, V = decompose_projection(P[:3])
        np.testing.assert_allclose(K, K0, rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(V[:3, :3], R, atol=1e-9)
    np.savez(tmp_path / "cameras_sphere.npz", **data)
    ims = [np.full((H, W, 3), 0.5, np.float32)] * n
    _write_images(str(tmp_path / "images_4"), ims, "{:06d}.png")
    masks = [np.zeros((H * 4, W * 4), np.float32) for _ in range(n)]
    masks[0][:, : W * 2] = 1.0  # left half
    _write_images(str(tmp_path / "mask"), masks, "{:03d}.png")
    sc = load_scene(str(tmp_path), calib_size=(W * 4, H * 4))
    assert sc.kind == "dtu" and len(sc) == n and sc.images[0].shape == (H, W, 3)
    np.testing.assert_allclose(sc.cameras[0].K[:2], K0[:2] / 4, atol=1e-6)
    # a point of the unit sphere frame projects where P projects its DTU-world image
    x = np.array([0.2, -0.1, 0.3])
    X = scale[:3, :3] @ x + scale[:3, 3]
    for i, cam in enumerate(sc.cameras):
        p = data[f"world_mat_{i}"][:3] @ np.append(X, 1)
        np.testing.assert_allclose(project(cam, x)[0], p[:2] / p[2] / 4, atol=1e-6)
    # bounds bracket the unit sphere; masks resized to the image
    d0 = np.linalg.norm(sc.cameras[0].center)
    np.testing.assert_allclose(sc.bounds[0], [d0 - 1, d0 + 1])
    assert d0 == pytest.approx(3.5)
    # (Pillow's bicubic, as DNGaussian's metrics_dtu.py: the columns at the edge are soft)
    m0 = sc.masks[0]
    assert m0.shape == (H, W) and m0[:, : W // 2 - 2].min() == 1 and m0[:, W // 2 + 2:].max() == 0
    assert 0 < m0[0, W // 2 - 1] < 1 or 0 < m0[0, W // 2] < 1


@pytest.mark.parametrize("shape,size", [((1200, 1600), (400, 300)), ((37, 53), (13, 10)), ((20, 30), (61, 45)),
                                        ((300, 400), (200, 300)), ((64, 64), (5, 17))])
def test_resize_u8_pil_is_pillow_bit_for_bit(shape, size):
    """images.resize_u8_pil against Pillow itself (the independent reference): random bytes and a
    disc mask, downscales by integer and fractional factors, an upscale."""
    Image = pytest.importorskip("PIL.Image")
    from reings.data.images import eval_mask, resize_u8_pil

    rng = np.random.default_rng(list(shape) + list(size))
    h, w = shape
    y, x = np.mgrid[0:h, 0:w]
    disc = ((((x - w / 2) / (w / 3)) ** 2 + ((y - h / 2) / (h / 3)) ** 2) < 1).astype(np.uint8) * 255
    for a in (rng.integers(0, 256, shape, dtype=np.uint8), disc):
        np.testing.assert_array_equal(resize_u8_pil(a, *size), np.asarray(Image.fromarray(a).resize(size)))
    rgb = np.stack([disc, np.roll(disc, 3, axis=1), disc], axis=2)  # channels that differ at the edges
    want = np.asarray(Image.fromarray(rgb).resize(size)).min(axis=2).astype(np.float32) / 255
    np.testing.assert_array_equal(eval_mask(rgb, *size), want)
    np.testing.assert_array_equal(eval_mask(rgb.astype(np.float32) / 255, *size), want)


def test_dtu_regnerf_calibration(tmp_path):
    n, W, H = 2, 40, 30
    K0 = np.array([[2892.3, 0, 823.2], [0, 2883.2, 619.1], [0, 0, 1]])
    cal = tmp_path / "Calibration" / "cal18"
    cal.mkdir(parents=True)
    scan = tmp_path / "Rectified" / "scan1"
    for i in range(n):
        R = _rot(1, 0.2 * i)
        t = np.array([0.0, 0.0, 600.0 + i])
        P = K0 @ np.concatenate([R, t[:, None]], 1)
        np.savetxt(cal / f"pos_{i + 1:03d}.txt", P)
    _write_images(str(scan), [np.zeros((H * 4, W * 4, 3), np.float32)] * n, "rect_{:03d}_3_r5000.png")
    _write_images(str(scan), [np.ones((H * 4, W * 4, 3), np.float32)] * n, "rect_{:03d}_0_r5000.png")
    sc = load_scene(str(scan), dataset="dtu", calib_size=(W * 4, H * 4), normalize=False)
    assert len(sc) == n and sc.images[0].shape == (H, W, 3) and sc.images[0].max() == 0  # light 3 only
    np.testing.assert_allclose(sc.cameras[1].viewmat[:3, :3], _rot(1, 0.2), atol=1e-9)
    np.testing.assert_allclose(sc.cameras[1].viewmat[:3, 3], [0, 0, 601], atol=1e-6)


# ---------------------------------------------------------------- Blender

def test_blender_opengl_to_opencv(tmp_path):
    w, h = 20, 10
    rgba = np.zeros((h, w, 4), np.float32)
    rgba[:, :, 0] = 1.0
    rgba[:, : w // 2, 3] = 1.0  # left half opaque red, right half transparent
    import cv2

    cv2.imwrite(str(tmp_path / "r_0.png"), (rgba[:, :, [2, 1, 0, 3]] * 255).astype(np.uint8))
    # OpenGL camera at (0, 0, 4) with identity rotation looks along -z, at the origin, y up
    M = np.eye(4)
    M[2, 3] = 4.0
    meta = {"camera_angle_x": 2 * np.arctan(0.5), "frames": [{"file_path": "./r_0", "transform_matrix": M.tolist()}]}
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    sc = load_scene(str(tmp_path))
    assert sc.kind == "blender" and sc.splits == ["train"] and sc.names == ["train/r_0.png"]
    cam = sc.cameras[0]
    assert cam.fx == pytest.approx(w)  # 0.5 W / tan(0.5 * angle) with tan = 0.5
    uv, z = project(cam, [0, 0, 0])
    np.testing.assert_allclose(uv, [w / 2, h / 2], atol=1e-9)
    assert z == pytest.approx(4.0)
    assert project(cam, [1, 0, 0])[0][0] > w / 2 and project(cam, [0, 1, 0])[0][1] < h / 2
    np.testing.assert_allclose(sc.images[0][0, 0], [1, 0, 0], atol=1e-6)  # opaque red
    np.testing.assert_allclose(sc.images[0][0, -1], [1, 1, 1], atol=1e-6)  # white background
    assert sc.masks[0][0, 0] == 1 and sc.masks[0][0, -1] == 0


def test_scene_validation_and_repr():
    ims, cams = _tiny_views(n=2)
    sc = Scene(ims, cams, ["a", "b"])
    assert "views=2" in repr(sc)
    with pytest.raises(ValueError, match="cameras"):
        Scene(ims, cams[:1], ["a", "b"])
    with pytest.raises(ValueError, match="camera is"):
        Scene([ims[0][:5]], cams[:1], ["a"])


def test_dtu_mask_of_another_aspect_is_refused(tmp_path):
    """Issue 14 item 4: a mask of the wrong size was stretched to the image silently; masks now
    get the images' aspect check and the error names the mask file."""
    from reings.data.types import SceneError

    n, W, H = 2, 40, 30
    K0 = np.array([[2892.3, 0.0, 823.2], [0, 2883.2, 619.1], [0, 0, 1]])
    data = {}
    for i in range(n):
        R = _rot(1, 0.1 * i)
        C = R.T @ np.array([0, 0, -700.0])
        P = np.eye(4)
        P[:3, :4] = K0 @ np.concatenate([R, (-R @ C)[:, None]], 1)
        data[f"world_mat_{i}"], data[f"scale_mat_{i}"] = P, np.diag([200.0, 200.0, 200.0, 1.0])
    np.savez(tmp_path / "cameras_sphere.npz", **data)
    _write_images(str(tmp_path / "images_4"), [np.full((H, W, 3), 0.5, np.float32)] * n, "{:06d}.png")
    masks = [np.ones((H * 4, W * 4), np.float32), np.ones((H * 4, W * 2), np.float32)]  # the second: 80x120
    _write_images(str(tmp_path / "mask"), masks, "{:03d}.png")
    with pytest.raises(SceneError, match=r"mask/001.png: 80x120 does not have DTU's"):
        load_scene(str(tmp_path), calib_size=(W * 4, H * 4))
    sc = load_scene(str(tmp_path), calib_size=(W * 4, H * 4), load_masks=False)  # images alone still load
    assert len(sc) == n
