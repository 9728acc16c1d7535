"""Depth priors: ONNX loading/pre/post-processing with tiny graphs built here, the stereo prior on
synthetic posed views with exact depth, the on-disk cache, bad input."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from reings.types import Camera

pytest.importorskip("cv2")
from reings.data import depth_prior as DP  # noqa: E402

have_onnx = importlib.util.find_spec("onnx") is not None and importlib.util.find_spec("onnxruntime") is not None
needs_onnx = pytest.mark.skipif(not have_onnx, reason="onnx / onnxruntime not installed")


# ------------------------------------------------------------------------------------- tiny graphs


def _graph(path, in_shape, name="image", op="mean", layout="NCHW", graph_name="tiny", out_4d=False):
    """x -> channel mean ([1, H, W] or [1, 1, H, W]) or -> 2 * channel 0 + 1."""
    import onnx
    from onnx import TensorProto, helper

    nodes = []
    axis = 1 if layout == "NCHW" else 3
    if op == "mean":
        ax = helper.make_tensor("axes", TensorProto.INT64, [1], [axis])
        nodes.append(helper.make_node("ReduceMean", ["x_in", "axes"], ["y"], keepdims=1 if out_4d else 0))
        inits = [ax]
    else:
        raise ValueError(op)
    nodes.insert(0, helper.make_node("Identity", [name], ["x_in"]))
    out_shape = [1, 1, "oh", "ow"] if out_4d else [1, "oh", "ow"]
    g = helper.make_graph(
        nodes,
        graph_name,
        [helper.make_tensor_value_info(name, TensorProto.FLOAT, in_shape)],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, out_shape)],
        initializer=inits,
    )
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    onnx.save(m, str(path))
    return path


def _image(rng, H=60, W=80):
    import cv2

    small = rng.random((H // 8 + 1, W // 8 + 1, 3)).astype(np.float32)
    return np.clip(cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC), 0, 1)


def test_input_sizes():
    assert DP.da_input_size(378, 504) == (518, 686)  # docs/method.md §7: 4:3 -> 686x518
    assert DP.midas_input_size(378, 504) == (384, 512)  # 4:3 -> 512x384
    assert DP.da_input_size(300, 400) == (518, 686)
    h, w = DP.da_input_size(600, 200)
    assert h % 14 == 0 and w % 14 == 0 and min(h, w) >= 518
    assert DP.midas_input_size(300, 400) == (288, 384)


@needs_onnx
def test_onnx_depth_anything_pipeline(tmp_path, rng):
    import cv2

    p = _graph(tmp_path / "tiny.onnx", [1, 3, "h", "w"])
    prior = DP.get_depth_prior(f"onnx:{p}", cache_dir=tmp_path / "c", conversion="disparity")
    assert prior.preprocess == "depth_anything"  # dynamic size, no name hint: ReInGS default
    img = _image(rng)
    x = prior.prepare(img)
    assert x.shape[:2] == (1, 3) and x.dtype == np.float32
    assert x.shape[2:] == DP.da_input_size(60, 80)
    # independent computation of what the graph returns, then resized back
    big = cv2.resize(img, (x.shape[3], x.shape[2]), interpolation=cv2.INTER_CUBIC)
    norm = (big - np.array([0.485, 0.456, 0.406], np.float32)) / np.array([0.229, 0.224, 0.225], np.float32)
    want = cv2.resize(norm.mean(-1), (80, 60), interpolation=cv2.INTER_LINEAR)
    got = prior.compute([img])[0]
    assert got.shape == (60, 80) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-4)


@needs_onnx
def test_onnx_midas_and_detection(tmp_path, rng):
    import cv2

    img = _image(rng, 90, 120)
    # fixed 384x384 input -> midas, fed exactly that size
    p = _graph(tmp_path / "m.onnx", [1, 3, 384, 384], name="0", out_4d=True)
    pr = DP.OnnxDepthPrior(p, conversion="disparity", cache=False)
    assert pr.preprocess == "midas" and pr.fixed_hw == (384, 384)
    big = cv2.resize(img, (384, 384), interpolation=cv2.INTER_CUBIC)
    want = cv2.resize(((big - 0.5) / 0.5).mean(-1), (120, 90), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(pr.predict(img), want, atol=1e-4)
    # fixed 518x518 -> depth anything
    p2 = _graph(tmp_path / "d.onnx", [1, 3, 518, 518])
    assert DP.OnnxDepthPrior(p2, cache=False).preprocess == "depth_anything"
    # dynamic size, detected by name -> midas keep-aspect multiples of 32
    p3 = _graph(tmp_path / "dpt_hybrid.onnx", [1, 3, "h", "w"])
    pr3 = DP.OnnxDepthPrior(p3, cache=False)
    assert pr3.preprocess == "midas"
    assert pr3.prepare(np.zeros((378, 504, 3), np.float32)).shape == (1, 3, 384, 512)
    # explicit option wins
    assert DP.OnnxDepthPrior(p3, preprocess="depth_anything", cache=False).preprocess == "depth_anything"
    # NHWC layout
    p4 = _graph(tmp_path / "nhwc.onnx", [1, "h", "w", 3], layout="NHWC")
    pr4 = DP.OnnxDepthPrior(p4, conversion="disparity", cache=False)
    assert pr4.layout == "NHWC"
    assert pr4.prepare(img).shape == (1,) + DP.da_input_size(90, 120) + (3,)
    assert pr4.predict(img).shape == (90, 120)


@needs_onnx
def test_onnx_conversion(tmp_path, rng):
    """Output = brightness as 'disparity': converted maps are decreasing in it."""
    p = _graph(tmp_path / "tiny.onnx", [1, 3, "h", "w"])
    img = _image(rng)
    raw = DP.OnnxDepthPrior(p, conversion="disparity", cache=False).predict(img)
    neg = DP.OnnxDepthPrior(p, cache=False).predict(img)
    inv = DP.OnnxDepthPrior(p, conversion="inverse", eps=0.1, cache=False).predict(img)
    dn = (raw - raw.min()) / (raw.max() - raw.min())
    np.testing.assert_allclose(neg, 1 - dn, atol=1e-5)
    np.testing.assert_allclose(inv, 1 / (dn + 0.1), rtol=1e-4)
    assert neg.min() == pytest.approx(0, abs=1e-6) and neg.max() == pytest.approx(1, abs=1e-6)


@needs_onnx
def test_onnx_cache(tmp_path, rng):
    p = _graph(tmp_path / "tiny.onnx", [1, 3, "h", "w"])
    cdir = tmp_path / "cache"
    imgs = [_image(rng), _image(rng)]
    pr = DP.get_depth_prior(f"onnx:{p}", cache_dir=cdir)
    d1 = pr.compute(imgs)
    assert pr.stats == {"hits": 0, "misses": 2}
    files = sorted(cdir.glob("onnx-*.npz"))
    assert len(files) == 2 and not list(cdir.glob(".tmp-*"))
    pr2 = DP.get_depth_prior(f"onnx:{p}", cache_dir=cdir)
    d2, c2 = pr2.compute(imgs, return_confidence=True)
    assert pr2.stats == {"hits": 2, "misses": 0} and c2 == [None, None]
    for a, b in zip(d1, d2):
        np.testing.assert_array_equal(a, b)
    # other settings -> other key; changed image -> miss for that image only
    pr3 = DP.get_depth_prior(f"onnx:{p}", cache_dir=cdir, conversion="inverse")
    pr3.compute(imgs)
    assert pr3.stats["misses"] == 2
    imgs2 = [imgs[0], np.clip(imgs[1] + 0.01, 0, 1)]
    pr2.compute(imgs2)
    assert pr2.stats == {"hits": 3, "misses": 1}
    # a corrupt cache file is recomputed, not trusted
    files[0].write_bytes(b"garbage")
    pr4 = DP.get_depth_prior(f"onnx:{p}", cache_dir=cdir)
    d4 = pr4.compute(imgs)
    for a, b in zip(d1, d4):
        np.testing.assert_array_equal(a, b)
    # cache=False writes nothing
    pr5 = DP.get_depth_prior(f"onnx:{p}", cache_dir=tmp_path / "none", cache=False)
    pr5.compute(imgs)
    assert not (tmp_path / "none").exists()


@needs_onnx
def test_onnx_bad_files(tmp_path):
    with pytest.raises(DP.DepthPriorError, match="missing.onnx"):
        DP.get_depth_prior(f"onnx:{tmp_path / 'missing.onnx'}")
    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"\x08\x07garbage that is not protobuf")
    with pytest.raises(DP.DepthPriorError, match="broken.onnx"):
        DP.get_depth_prior(f"onnx:{bad}")
    good = _graph(tmp_path / "tiny.onnx", [1, 3, "h", "w"])
    trunc = tmp_path / "trunc.onnx"
    trunc.write_bytes(good.read_bytes()[:40])
    with pytest.raises(DP.DepthPriorError, match="trunc.onnx"):
        DP.get_depth_prior(f"onnx:{trunc}")
    wrong = _graph(tmp_path / "wrong.onnx", [1, 5, "h", "w"])
    with pytest.raises(DP.DepthPriorError, match="wrong.onnx"):
        DP.get_depth_prior(f"onnx:{wrong}")
    pr = DP.get_depth_prior(f"onnx:{good}", cache=False)
    with pytest.raises(DP.DepthPriorError, match=r"\(H, W, 3\)"):
        pr.compute([np.zeros((10, 10))])
    nan = np.zeros((10, 10, 3), np.float32)
    nan[0, 0, 0] = np.nan
    with pytest.raises(DP.DepthPriorError, match="non-finite"):
        pr.compute([nan])
    with pytest.raises(DP.DepthPriorError, match="unknown option"):
        DP.get_depth_prior(f"onnx:{good}", window=3)


def test_kinds():
    assert DP.get_depth_prior("none").enabled is False
    assert DP.get_depth_prior("none").compute([np.zeros((4, 4, 3))]) == [None]
    with pytest.raises(DP.DepthPriorError, match="unknown kind"):
        DP.get_depth_prior("midas")
    with pytest.raises(DP.DepthPriorError, match="needs a model path"):
        DP.get_depth_prior("onnx:")
    with pytest.raises(DP.DepthPriorError, match="unknown option"):
        DP.get_depth_prior("stereo", windw=5)


# ------------------------------------------------------------------------------------- stereo


def _texture(rng, n=256):
    import cv2

    t = np.zeros((n, n, 3), np.float32)
    for s, a in ((2, 0.5), (4, 0.3), (16, 0.3), (64, 0.2)):
        small = rng.random((n // s + 2, n // s + 2, 3)).astype(np.float32)
        t += a * cv2.resize(small, (n, n), interpolation=cv2.INTER_CUBIC)
    t -= t.min()
    return t / t.max()


def _sample(tex, u, v, scale):
    import cv2

    n = tex.shape[0]
    mu = ((u * scale) % n).astype(np.float32)
    mv = ((v * scale) % n).astype(np.float32)
    return cv2.remap(tex, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def plane_views(n_views=3, W=200, H=150, f=170.0, baseline=0.6, seed=0):
    """Ray-traced by numpy: a tilted textured background plane z = 8 + 0.15 x and a textured
    square z = 4, |x|, |y| < 1.2; cameras side by side, slightly toed in. Exact z-depth."""
    rng = np.random.default_rng(seed)
    t1, t2 = _texture(rng), _texture(rng)
    imgs, cams, deps = [], [], []
    for i in range(n_views):
        cx = (i - (n_views - 1) / 2) * baseline
        yaw = -0.03 * cx
        R = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        C = np.array([cx, 0.1 * i, 0.0])
        V = np.eye(4)
        V[:3, :3] = R.T
        V[:3, 3] = -R.T @ C
        K = np.array([[f, 0, W / 2 + 1.5], [0, f, H / 2 - 1], [0, 0, 1]])
        xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        d_w = np.stack([(xs - K[0, 2]) / f, (ys - K[1, 2]) / f, np.ones_like(xs)], -1) @ R.T
        s_bg = (8 + 0.15 * C[0] - C[2]) / (d_w[..., 2] - 0.15 * d_w[..., 0])
        s_fg = (4 - C[2]) / d_w[..., 2]
        Pf = C + s_fg[..., None] * d_w
        Pb = C + s_bg[..., None] * d_w
        fg = (np.abs(Pf[..., 0]) < 1.2) & (np.abs(Pf[..., 1]) < 1.2)
        img = np.where(
            fg[..., None], _sample(t1, Pf[..., 0] + 5, Pf[..., 1] + 5, 26), _sample(t2, Pb[..., 0] + 9, Pb[..., 1] + 9, 26)
        )
        imgs.append(img.astype(np.float32))
        cams.append(Camera(K, V, W, H))
        deps.append(np.where(fg, s_fg, s_bg).astype(np.float32))
    return imgs, cams, deps


class _Views:
    def __init__(self, images, cameras, points=None):
        self.images, self.cameras, self.points = images, cameras, points
        self.names = [f"v{i}" for i in range(len(images))]


def _err(d, g, m):
    e = np.abs(d[m] - g[m]) / g[m]
    return e.mean(), (e < 0.05).mean()


def test_stereo_recovers_planes():
    from reings.data.stereo import stereo_depths

    imgs, cams, deps = plane_views()
    res = stereo_depths(imgs, cams)
    for r, g in zip(res, deps):
        assert r.depth.shape == g.shape and r.depth.dtype == np.float32
        assert np.all(np.isfinite(r.depth)) and np.all(r.depth > 0)
        assert 0 <= r.confidence.min() and r.confidence.max() <= 1
        conf = r.confidence >= 0.3
        assert conf.mean() > 0.5
        absrel_c, w5_c = _err(r.raw_depth, g, conf)
        assert absrel_c < 0.03 and w5_c > 0.95
        absrel_all, w5_all = _err(r.depth, g, np.ones_like(conf))
        assert absrel_all < 0.08 and w5_all > 0.8


def test_stereo_prior_cache_and_range(tmp_path):
    imgs, cams, deps = plane_views(n_views=2, W=160, H=120, f=140.0)
    cdir = tmp_path / "c"
    pr = DP.get_depth_prior("stereo", cache_dir=cdir, num_depths=64)
    d, c = pr.compute(_Views(imgs, cams), return_confidence=True)
    assert pr.stats == {"hits": 0, "misses": 2}
    assert len(d) == 2 and c[0].shape == d[0].shape == (120, 160)
    pr2 = DP.get_depth_prior("stereo", cache_dir=cdir, num_depths=64)
    d2, c2 = pr2.compute(_Views(imgs, cams), return_confidence=True)
    assert pr2.stats == {"hits": 2, "misses": 0}
    np.testing.assert_array_equal(d[1], d2[1])
    np.testing.assert_array_equal(c[0], c2[0])
    # a moved camera changes every view's key (stereo depends on all views)
    V = cams[1].viewmat.copy()
    V[0, 3] += 0.01
    cams2 = [cams[0], Camera(cams[1].K, V, 160, 120)]
    pr2.compute(_Views(imgs, cams2))
    assert pr2.stats["misses"] == 2
    # sparse points (from these views) set the depth range
    from reings.data.stereo import depth_range

    pts = np.array([[0, 0, 4.0], [1, 1, 9.0]] * 8)
    n, f = depth_range(cams, 0, points=pts)
    assert n == pytest.approx(0.8 * np.percentile(pts @ cams[0].viewmat[:3, :3].T[:, 2] + cams[0].viewmat[2, 3], 1))
    assert f > 9.0


def test_stereo_bad_input():
    imgs, cams, _ = plane_views(n_views=2, W=64, H=48, f=60.0)
    pr = DP.get_depth_prior("stereo", cache=False)
    with pytest.raises(DP.DepthPriorError, match="at least 2"):
        pr.compute(_Views(imgs[:1], cams[:1]))
    with pytest.raises(DP.DepthPriorError, match="cameras"):
        pr.compute(imgs)  # a plain list has no cameras
    with pytest.raises(DP.DepthPriorError, match="baseline"):
        pr.compute(_Views(imgs, [cams[0], cams[0]]))


def test_stereo_on_procedural_scene():
    """If the procedural scene is available: the prior on 3 of its views, checked against exact depth."""
    proc = pytest.importorskip("reings.data.procedural")
    scene = proc.make_procedural_scene()
    if getattr(scene, "depths", None) is None:
        pytest.skip("procedural scene without exact depths")
    n = len(scene.images)
    idx = [round(j) for j in np.linspace(0, n - 1, 3)] if n >= 3 else list(range(n))
    sub = scene.subset(idx)
    from reings.data.stereo import stereo_depths

    res = stereo_depths(sub.images, sub.cameras)
    errs = []
    for r, g in zip(res, sub.depths):
        conf = np.isfinite(g) & (g > 0) & (r.confidence >= 0.3)
        assert conf.mean() > 0.3
        errs.append(_err(r.raw_depth, g, conf) + _err(r.depth, g, np.isfinite(g) & (g > 0)))
    absrel_c, w5_c, absrel_all, w5_all = np.mean(errs, axis=0)
    # measured (200x150, views 0/12/23): confident 0.044 / 0.92, all (filled) 0.090 / 0.74
    assert absrel_c < 0.08 and w5_c > 0.85
    assert absrel_all < 0.15 and w5_all > 0.65


@needs_onnx
def test_onnx_degenerate_outputs_are_refused(tmp_path):
    """Issue 14 item 7: a 1x1 output was resized into a constant depth map and accepted."""
    pr = DP.get_depth_prior(f"onnx:{_graph(tmp_path / 'tiny.onnx', [1, 3, 'h', 'w'])}", cache=False)
    for out in (np.ones((1, 1, 1), np.float32), np.ones((1, 1, 1, 1), np.float32), np.ones((1, 4, 60), np.float32)):
        with pytest.raises(DP.DepthPriorError, match="too small to be the depth map of a 80x60 image"):
            pr.postprocess(out, 60, 80)
    with pytest.raises(DP.DepthPriorError, match="constant map"):
        pr.postprocess(np.full((1, 60, 80), 3.0, np.float32), 60, 80)
    assert pr.postprocess(np.arange(60 * 80, dtype=np.float32).reshape(1, 60, 80), 60, 80).shape == (60, 80)


def _slanted_plane_pair(yaw_deg=50.0, z0=5.0, W=160, H=120, f=150.0, seed=3):
    """Two views of one textured plane through (0, 0, z0) of view 0's frame, its normal turned by
    yaw_deg about y (stereo._plane_normal); view 1 is 1.2 to the right, toed in by 10 degrees.
    Ray-traced by numpy; returns images, cameras and view 0's exact z-depth."""
    from reings.data.stereo import _plane_normal

    rng = np.random.default_rng(seed)
    tex = _texture(rng)
    n = _plane_normal(yaw_deg, 0.0)
    d = n[2] * z0
    u_axis = np.cross([0.0, 1.0, 0.0], n)
    u_axis /= np.linalg.norm(u_axis)
    imgs, cams, dep0 = [], [], None
    for C, yaw in ((np.zeros(3), 0.0), (np.array([1.2, 0.0, 0.0]), np.radians(-10.0))):
        R = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        V = np.eye(4)
        V[:3, :3] = R.T
        V[:3, 3] = -R.T @ C
        K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
        xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        d_w = np.stack([(xs - K[0, 2]) / f, (ys - K[1, 2]) / f, np.ones_like(xs)], -1) @ R.T
        s = (d - n @ C) / (d_w @ n)
        P = C + s[..., None] * d_w
        imgs.append(_sample(tex, P @ u_axis + 5, P[..., 1] + 5, 26).astype(np.float32))
        cams.append(Camera(K, V, W, H))
        if dep0 is None:
            dep0 = (s * d_w[..., 2]).astype(np.float32)
    return imgs, cams, dep0


def test_stereo_slanted_sweep_homography():
    """Planes of the plane's own normal align the two views exactly: the best-scoring plane at each
    pixel has the true inverse depth (within one plane step); fronto-parallel planes do worse there."""
    import cv2

    from reings.data.stereo import _gray, _plane_normal, _sweep

    imgs, cams, dep = _slanted_plane_pair()
    grays = [_gray(i) for i in imgs]
    invd = np.linspace(1 / 12.0, 1 / 2.5, 160)
    step = invd[1] - invd[0]
    inner = np.zeros(dep.shape, bool)
    inner[15:-15, 30:-30] = True
    errs = {}
    for tag, normal in (("slanted", _plane_normal(50.0, 0.0)), ("fronto", None)):
        vol, _, rho = _sweep(cv2, 0, grays, cams, invd, 9, 0.004, normal)
        q = invd[np.argmax(vol, axis=0)] * rho
        ok = inner & (vol.max(0) > -1)
        errs[tag] = np.abs(q - 1.0 / dep)[ok] / step
    assert np.median(errs["slanted"]) <= 1.0 and np.mean(errs["slanted"] <= 1.5) > 0.9
    assert np.mean(errs["slanted"] <= 1.5) > np.mean(errs["fronto"] <= 1.5)


def test_stereo_slants_and_bounds():
    """`slants` adds plane orientations (a 50-degree plane is recovered better with them); `bounds`
    sets each view's depth range, checked before any work."""
    from reings.data.stereo import stereo_depths

    imgs, cams, dep = _slanted_plane_pair()
    m = np.zeros(dep.shape, bool)
    m[15:-15, 30:-30] = True
    b = np.array([[2.5, 12.0], [2.5, 12.0]])
    plain = stereo_depths(imgs, cams, bounds=b)[0]
    slanted = stereo_depths(imgs, cams, bounds=b, slants=((50.0, 0.0),))[0]
    assert (plain.near, plain.far) == (2.5, 12.0)
    e_plain = np.abs(plain.raw_depth - dep)[m] / dep[m]
    e_slant = np.abs(slanted.raw_depth - dep)[m] / dep[m]
    assert np.median(e_slant) < 0.01 and np.mean(e_slant < 0.02) >= np.mean(e_plain < 0.02)
    for bad in ([[2.5, 12.0]], [[0.0, 12.0], [2.5, 12.0]], [[5.0, 4.0], [2.5, 12.0]], [[np.nan, 12.0], [2.5, 12.0]]):
        with pytest.raises(ValueError, match="bounds"):
            stereo_depths(imgs, cams, bounds=bad)


class _BoundedViews(_Views):
    def __init__(self, images, cameras, bounds):
        super().__init__(images, cameras)
        self.bounds = bounds


def test_stereo_prior_settings_and_bounds_key(tmp_path):
    """The cache key holds every setting with the defaults resolved (a changed default cannot hit an
    old file); use_bounds passes the views' bounds and keys them; with_options keeps the cache."""
    import inspect

    from reings.data.stereo import stereo_depths

    pr = DP.get_depth_prior("stereo", cache_dir=tmp_path / "c")
    opts = pr._settings()["options"]
    assert opts["sgm_p1"] == inspect.signature(stereo_depths).parameters["sgm_p1"].default
    assert opts["use_bounds"] is False and "bounds" not in opts
    wide = pr.with_options(sgm_p1=0.2, use_bounds=True)
    assert wide.cache_dir == pr.cache_dir and wide._settings() != pr._settings()
    with pytest.raises(DP.DepthPriorError, match="unknown option"):
        pr.with_options(bounds=[[1, 2]])
    imgs, cams, _ = plane_views(n_views=2, W=64, H=48, f=60.0)
    geo_b = (None, np.array([[3.0, 3.5], [3.0, 3.5]]))  # nearer than the scene (4 and ~8): only the bounds put it there
    assert pr._keys(imgs, cams, geo_b) == pr._keys(imgs, cams, (None, None))  # bounds unused: same key
    assert wide._keys(imgs, cams, geo_b) != wide._keys(imgs, cams, (None, None))
    d, _ = wide.with_options(num_depths=32).compute(_BoundedViews(imgs, cams, geo_b[1]), return_confidence=True)
    assert all(np.all((x >= 3.0 - 1e-4) & (x <= 3.5 + 1e-4)) for x in d)


def test_stereo_settings_per_recipe_family():
    from reings.pipeline import STEREO_BY_FAMILY, prior_for_family

    pr = DP.get_depth_prior("stereo", cache=False)
    assert prior_for_family(pr, "llff") is pr
    dtu = prior_for_family(pr, "dtu")
    assert dtu.options == STEREO_BY_FAMILY["dtu"] and dtu.options["use_bounds"] is True
    mine = pr.with_options(sgm_p1=0.05)
    assert prior_for_family(mine, "dtu") is mine  # a user's own settings are kept
    none = DP.get_depth_prior("none")
    assert prior_for_family(none, "dtu") is none


def test_stereo_spec_options():
    """'stereo:k=v,...' sets the stereo prior's options (numbers, True/False), named errors otherwise."""
    pr = DP.get_depth_prior("stereo:sgm_p1=0.03, sgm_p2=0.6,use_bounds=False", cache=False)
    assert pr.kind == "stereo" and pr.options == {"sgm_p1": 0.03, "sgm_p2": 0.6, "use_bounds": False}
    assert DP.prior_kind("stereo:sgm_p1=1") == DP.prior_kind(" Stereo ") == "stereo"
    assert DP.prior_kind("onnx:/x/y.onnx") == "onnx" and DP.prior_kind("none") == "none"
    for bad, msg in (("stereo:sgm_p1=abc", "sgm_p1"), ("stereo:sgm_p1=nan", "finite"), ("stereo:window", "k=v"),
                     ("stereo:sgm_p3=1", "unknown option"), ("stereo:slants=((35,0),)", "slants")):
        with pytest.raises(DP.DepthPriorError, match=msg):
            DP.get_depth_prior(bad, cache=False)
