"""Camera paths (reings.paths) against their definitions: the spiral looks at its focus point
and moves within the training cameras' spread, the ellipse loops around the focus point of the
optical axes, interpolation starts and ends at the given cameras, slerp against the analytic
half-angle rotation."""
from __future__ import annotations

import numpy as np
import pytest

from reings.paths import (average_camera, camera_path, depth_range, ellipse, focus_point, interpolate, look_at,
                          slerp, spiral, _quat, _rot)
from reings.types import Camera

K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])


def _forward_facing(n=4, seed=0):
    """Cameras near the origin looking roughly along +z (LLFF-like)."""
    rng = np.random.default_rng(seed)
    cams = []
    for _ in range(n):
        c = rng.uniform(-0.3, 0.3, 3) * [1, 0.6, 0.1]
        target = np.array([0.0, 0.0, 5.0]) + rng.normal(0, 0.2, 3)
        cams.append(look_at(c, target, np.array([0.0, -1.0, 0.0]), K, 64, 48))
    return cams


def _ring(n=5, radius=3.0, height=-1.0):
    """Cameras on an arc around the origin looking at it (DTU-like); world up = -y."""
    cams = []
    for a in np.linspace(-0.6, 0.6, n):
        c = np.array([radius * np.sin(a), height, -radius * np.cos(a)])
        cams.append(look_at(c, np.zeros(3), np.array([0.0, -1.0, 0.0]), K, 64, 48))
    return cams


def _assert_proper(cam: Camera):
    R = cam.viewmat[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert abs(np.linalg.det(R) - 1) < 1e-9


def test_look_at_points_the_optical_axis_at_the_target():
    cam = look_at(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.5, 7.0]), np.array([0.0, -1.0, 0.0]), K, 64, 48)
    _assert_proper(cam)
    p = cam.viewmat @ np.array([0.0, 0.5, 7.0, 1.0])
    assert abs(p[0]) < 1e-9 and abs(p[1]) < 1e-9 and p[2] > 0  # projects to the principal point


def test_spiral_looks_at_the_focus_and_stays_in_the_spread():
    cams = _forward_facing(6)
    c, right, down, fwd = average_camera(cams)
    near, far = 2.0, 8.0
    path = spiral(cams, 40, (near, far))
    focus = 1 / (0.25 / (0.9 * near) + 0.75 / (5 * far))
    target = c + focus * fwd
    off = np.array([cam.center - c for cam in cams]) @ np.stack([right, down, fwd]).T
    rads = np.percentile(np.abs(off), 90, axis=0)
    for cam in path:
        _assert_proper(cam)
        p = cam.viewmat @ np.append(target, 1.0)
        assert abs(p[0]) < 1e-8 and abs(p[1]) < 1e-8 and p[2] > 0
        o = (cam.center - c) @ np.stack([right, down, fwd]).T
        assert np.all(np.abs(o) <= rads + 1e-9)
        assert cam.viewmat[1, :3] @ down > 0.9  # image down stays the average camera's down
    xs = [(cam.center - c) @ right for cam in path]
    assert max(xs) == pytest.approx(rads[0], rel=1e-6)  # cos t reaches 1 at t = 0


def test_depth_range_weighted_percentiles():
    cams = [look_at(np.zeros(3), np.array([0, 0, 1.0]), np.array([0, -1.0, 0]), K, 64, 48)]
    z = np.linspace(1, 100, 100)
    pts = np.stack([np.zeros(100), np.zeros(100), z], 1)
    near, far = depth_range(cams, pts)
    assert near == 1.0 + 0.0 and 99 <= far <= 100
    w = np.where(z < 50, 0.0, 1.0)  # weight zero in front: the near end moves to 50
    assert depth_range(cams, pts, w)[0] == 50.0
    with pytest.raises(ValueError, match="fewer than 2"):
        depth_range(cams, -pts)


def test_focus_point_is_where_the_axes_meet():
    np.testing.assert_allclose(focus_point(_ring()), 0, atol=1e-9)


def test_ellipse_loops_around_the_focus_point():
    cams = _ring(5, radius=3.0, height=-1.0)
    path = ellipse(cams, 36)
    for cam in path:
        _assert_proper(cam)
        p = cam.viewmat @ np.array([0.0, 0, 0, 1])
        assert abs(p[0]) < 1e-8 and abs(p[1]) < 1e-8 and p[2] > 0  # looks at the focus point
    up = np.array([0.0, -1.0, 0.0])
    h = np.array([cam.center @ up for cam in path])
    np.testing.assert_allclose(h, 1.0, atol=1e-9)  # every ring camera at height 1: no height swing
    r = np.array([np.linalg.norm(cam.center - (cam.center @ up) * up) for cam in path])
    assert r.max() <= 3.0 + 1e-9 and r.min() >= 1.5 - 1e-9  # within the semi-axes, >= half the mean radius
    np.testing.assert_allclose(path[0].center, cams[0].center, atol=0.5 * 3)  # starts at the first camera's angle


def test_interpolate_starts_and_ends_at_the_cameras():
    cams = _forward_facing(3, seed=2)
    path = interpolate(cams, 21)
    np.testing.assert_allclose(path[0].viewmat, cams[0].viewmat, atol=1e-9)
    np.testing.assert_allclose(path[-1].viewmat, cams[-1].viewmat, atol=1e-9)
    for cam in path:
        _assert_proper(cam)
    with pytest.raises(ValueError, match="at least 2"):
        interpolate(cams[:1], 5)


def test_slerp_half_way_is_the_half_angle():
    Rz = lambda deg: _rot(_quat(np.array([[np.cos(np.radians(deg)), -np.sin(np.radians(deg)), 0],  # noqa: E731
                                          [np.sin(np.radians(deg)), np.cos(np.radians(deg)), 0], [0, 0, 1]])))
    q = slerp(_quat(Rz(0)), _quat(Rz(90)), 0.5)
    np.testing.assert_allclose(_rot(q), Rz(45), atol=1e-12)
    q = slerp(_quat(Rz(10)), _quat(Rz(10.001)), 0.5)  # nearly equal: the linear branch
    np.testing.assert_allclose(_rot(q), Rz(10.0005), atol=1e-9)


def test_camera_path_sizes_and_errors():
    cams = _forward_facing(3)
    pts = np.random.default_rng(0).uniform([-1, -1, 3], [1, 1, 9], (200, 3))
    path = camera_path("spiral", cams, 10, points=pts, size=(128, 96))
    assert len(path) == 10 and (path[0].width, path[0].height) == (128, 96)
    assert path[0].fx == pytest.approx(120.0) and path[0].cx == pytest.approx(64.0)
    with pytest.raises(ValueError, match="unknown path"):
        camera_path("zigzag", cams, 10)
    with pytest.raises(ValueError, match="frames must be a positive integer"):
        camera_path("interpolate", cams, 0)
    with pytest.raises(ValueError, match="spiral needs scene points"):
        camera_path("spiral", cams, 5)
