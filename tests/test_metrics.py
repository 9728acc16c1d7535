"""reings.metrics against independent computations (scikit-image, scipy, analytic values)."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from reings import metrics as M

from conftest import data_root


def _lpips_model():
    try:
        return M.find_lpips_model()
    except M.LPIPSModelNotFound:
        return None


def _have(mod):
    import importlib.util

    return importlib.util.find_spec(mod) is not None


needs_lpips = pytest.mark.skipif(
    not _have("onnxruntime") or _lpips_model() is None, reason="onnxruntime or lpips_vgg.onnx not available"
)


def _smooth_pair(rng, H=60, W=80):
    import scipy.ndimage as ndi

    a = ndi.gaussian_filter(rng.random((H, W, 3)), (2, 2, 0))
    a = (a - a.min()) / (a.max() - a.min())
    b = np.clip(a + 0.08 * rng.standard_normal(a.shape), 0, 1)
    return a, b


# ------------------------------------------------------------------------------------- PSNR


def test_psnr_analytic(rng):
    a = rng.random((20, 30, 3))
    b = a.copy()
    b[0, 0, 0] = a[0, 0, 0] + 0.1 if a[0, 0, 0] < 0.9 else a[0, 0, 0] - 0.1
    mse = 0.01 / (20 * 30 * 3)
    assert M.psnr(b, a) == pytest.approx(-10 * math.log10(mse), rel=1e-9)
    c = np.full((8, 8, 3), 0.5)
    assert M.psnr(c + 0.1, c) == pytest.approx(20.0, abs=1e-9)
    assert M.psnr(c, c) == math.inf


def test_psnr_masked(rng):
    a = rng.random((10, 12, 3))
    b = a.copy()
    m = np.zeros((10, 12), bool)
    m[2:5, 3:9] = True
    b[~m] = 0.0  # differences outside the mask are ignored
    assert M.psnr(b, a, mask=m) == math.inf
    b[m] = np.clip(a[m] + 0.05, 0, 1)
    mse = np.mean((b[m] - a[m]) ** 2)
    assert M.psnr(b, a, mask=m.astype(np.float32)) == pytest.approx(-10 * np.log10(mse), rel=1e-9)
    with pytest.raises(ValueError, match="no foreground"):
        M.psnr(a, b, mask=np.zeros((10, 12)))
    with pytest.raises(ValueError, match="mask"):
        M.psnr(a, b, mask=np.ones((10, 11)))


# ------------------------------------------------------------------------------------- SSIM


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_ssim_skimage_equal(rng, dtype):
    skm = pytest.importorskip("skimage.metrics")
    for H, W in ((60, 80), (33, 47), (7, 9)):
        a, b = _smooth_pair(rng, H, W)
        a, b = a.astype(dtype), b.astype(dtype)
        ref = skm.structural_similarity(a, b, data_range=1, channel_axis=-1)
        tol = 1e-10 if dtype == np.float64 else 2e-5
        assert M.ssim(a, b, kind="skimage") == pytest.approx(ref, abs=tol)


def test_ssim_gs_matches_scipy_conv(rng):
    """3DGS SSIM: torch conv2d(padding=5, groups=3) == scipy correlate2d 'same' with zero fill."""
    sig = pytest.importorskip("scipy.signal")
    a, b = _smooth_pair(rng, 40, 50)
    x = np.arange(11) - 5
    g = np.exp(-(x**2) / (2 * 1.5**2))
    g /= g.sum()
    w = np.outer(g, g)

    def f(img):
        return np.stack([sig.correlate2d(img[..., c], w, mode="same", boundary="fill") for c in range(3)], -1)

    mu1, mu2 = f(a), f(b)
    s11 = f(a * a) - mu1**2
    s22 = f(b * b) - mu2**2
    s12 = f(a * b) - mu1 * mu2
    C1, C2 = 0.01**2, 0.03**2
    ref = (((2 * mu1 * mu2 + C1) * (2 * s12 + C2)) / ((mu1**2 + mu2**2 + C1) * (s11 + s22 + C2))).mean()
    assert M.ssim(a, b) == pytest.approx(ref, abs=1e-12)
    assert M.ssim(a, b, kind="gs") == M.ssim(a, b)


def test_ssim_identical_and_masked(rng):
    a, b = _smooth_pair(rng)
    assert M.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert M.ssim(a, a, kind="skimage") == pytest.approx(1.0, abs=1e-12)
    m = np.zeros(a.shape[:2])
    m[10:40, 10:50] = 1
    wa = a * m[..., None] + (1 - m[..., None])
    wb = b * m[..., None] + (1 - m[..., None])
    assert M.ssim(a, b, mask=m) == pytest.approx(M.ssim(wa, wb), abs=1e-12)
    with pytest.raises(ValueError, match="unknown kind"):
        M.ssim(a, b, kind="msssim")


# ------------------------------------------------------------------------------------- input checks


def test_bad_input(rng):
    a = rng.random((10, 10, 3))
    with pytest.raises(ValueError, match="shapes differ"):
        M.psnr(a, rng.random((10, 11, 3)))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        M.ssim(a[..., 0], a[..., 0])
    bad = a.copy()
    bad[3, 3, 1] = np.nan
    for f in (M.psnr, M.ssim):
        with pytest.raises(ValueError, match="non-finite"):
            f(bad, a)
    with pytest.raises(ValueError, match="uint8"):
        M.psnr((a * 255).astype(np.uint8), a)
    with pytest.raises(ValueError, match="NaN"):
        M.avge(float("nan"), 0.5, 0.2)


# ------------------------------------------------------------------------------------- AVGE


def test_avge_definition():
    p, s, lp = 20.0, 0.75, 0.2
    ref = (0.01 * 0.5 * 0.2) ** (1 / 3)
    assert M.avge(p, s, lp) == pytest.approx(ref, rel=1e-12)
    arr = M.avge(np.array([20.0, 30.0]), np.array([0.75, 0.96]), np.array([0.2, 0.1]))
    assert arr.shape == (2,)
    assert arr[1] == pytest.approx((1e-3 * 0.2 * 0.1) ** (1 / 3), rel=1e-12)
    assert M.avge(math.inf, 1.0, 0.0) == 0.0


# ------------------------------------------------------------------------------------- LPIPS


def test_lpips_missing_model(tmp_path, monkeypatch):
    with pytest.raises(M.LPIPSModelNotFound, match="does not exist"):
        M.find_lpips_model(tmp_path / "nope.onnx")
    monkeypatch.setenv("REINGS_LPIPS_MODEL", str(tmp_path / "nope.onnx"))
    with pytest.raises(FileNotFoundError, match="REINGS_LPIPS_MODEL"):
        M.lpips(np.zeros((64, 64, 3)), np.zeros((64, 64, 3)))


def test_lpips_unreadable_model(tmp_path):
    pytest.importorskip("onnxruntime")
    bad = tmp_path / "lpips_vgg.onnx"
    bad.write_bytes(b"this is not an onnx file")
    with pytest.raises(ValueError, match="lpips_vgg.onnx"):
        M.lpips(np.zeros((64, 64, 3)), np.zeros((64, 64, 3)), model=bad)


@needs_lpips
def test_lpips_properties(rng):
    a, b = _smooth_pair(rng, 64, 96)
    assert abs(M.lpips(a, a)) < 1e-6
    assert abs(M.lpips(a, a, convention="official")) < 1e-6
    d1 = M.lpips(a, b)
    assert d1 > 0.01
    assert M.lpips(a, b) == d1  # deterministic
    assert M.lpips(b, a) == pytest.approx(d1, rel=1e-5)  # symmetric
    assert M.lpips(a, b, convention="official") != pytest.approx(d1, rel=1e-3)
    c = np.clip(a + 0.3 * rng.standard_normal(a.shape), 0, 1)
    assert M.lpips(a, c) > d1  # more noise, larger distance
    with pytest.raises(ValueError, match="convention"):
        M.lpips(a, b, convention="torch")


@needs_lpips
def test_lpips_manifest_value():
    """docs/data.md ("Test data and models"): official-convention VGG LPIPS of fern image000/image001 is 0.314670."""
    root = Path(data_root() or "/work/shared/data")
    p0, p1 = root / "llff/fern/images_8/image000.png", root / "llff/fern/images_8/image001.png"
    if not (p0.is_file() and p1.is_file()):
        pytest.skip("fern images not available")
    cv2 = pytest.importorskip("cv2")
    a = cv2.imread(str(p0))[..., ::-1].astype(np.float32) / 255
    b = cv2.imread(str(p1))[..., ::-1].astype(np.float32) / 255
    assert M.lpips(a, b, convention="official") == pytest.approx(0.314670, abs=2e-6)


@needs_lpips
def test_evaluate_images(rng):
    pairs = [_smooth_pair(rng, 64, 80) for _ in range(3)]
    preds, refs = [p[1] for p in pairs], [p[0] for p in pairs]
    r = M.evaluate_images(preds, refs)
    assert r["n"] == 3
    for k in ("psnr", "ssim", "ssim_gs", "ssim_sk", "lpips", "avge"):
        assert len(r["per_image"][k]) == 3
        assert r[k] == pytest.approx(np.mean(r["per_image"][k]))
    assert r["per_image"]["psnr"][1] == pytest.approx(M.psnr(preds[1], refs[1]))
    assert r["avge"] == pytest.approx(np.mean(M.avge(np.array(r["per_image"]["psnr"]), np.array(r["per_image"]["ssim"]), np.array(r["per_image"]["lpips"]))))
    masks = [np.pad(np.ones((40, 40)), ((12, 12), (20, 20))) for _ in range(3)]
    rm = M.evaluate_images(preds, refs, masks)
    d = M.dtu_metrics(preds[0], refs[0], masks[0])
    for k in ("psnr", "ssim", "lpips", "avge"):
        assert rm["per_image"][k][0] == pytest.approx(d[k], rel=1e-9)
    with pytest.raises(ValueError, match="2 predictions but 3"):
        M.evaluate_images(preds[:2], refs)
    nl = M.evaluate_images(preds, refs, with_lpips=False, ssim_kind="skimage")
    assert nl["lpips"] is None and nl["ssim"] == nl["ssim_sk"]


@pytest.mark.data
@needs_lpips
def test_fern_consecutive_test_images(capsys):
    """Sanity numbers between consecutive fern test images (indices 0, 8, 16)."""
    root = data_root()
    if root is None:
        pytest.skip("REINGS_DATA not set")
    cv2 = pytest.importorskip("cv2")
    d = Path(root) / "llff/fern/images_8"
    names = sorted(os.listdir(d))
    test = [names[i] for i in range(len(names)) if i % 8 == 0]
    imgs = [cv2.imread(str(d / n))[..., ::-1].astype(np.float32) / 255 for n in test]
    r = M.evaluate_images(imgs[1:], imgs[:-1])
    with capsys.disabled():
        for i in range(len(imgs) - 1):
            print(
                f"\nfern {test[i + 1]} vs {test[i]}: PSNR {r['per_image']['psnr'][i]:.3f} SSIM(gs) "
                f"{r['per_image']['ssim_gs'][i]:.4f} SSIM(sk) {r['per_image']['ssim_sk'][i]:.4f} LPIPS(vgg,3dgs) "
                f"{r['per_image']['lpips'][i]:.4f} AVGE {r['per_image']['avge'][i]:.4f}"
            )
    # different viewpoints of one scene: low PSNR, mediocre SSIM, clearly non-zero LPIPS
    assert 10 < r["psnr"] < 20
    assert 0.1 < r["ssim"] < 0.7
    assert 0.15 < r["lpips"] < 0.7


def test_lpips_model_only_from_explicit_places(tmp_path, monkeypatch):
    """Issue 14 item 9: an lpips_vgg.onnx in the working directory replaced the model; now only
    the argument, REINGS_LPIPS_MODEL and the user cache's models folder count, and
    lpips_model_info gives the path and sha256 that metrics.json records."""
    import hashlib

    monkeypatch.delenv("REINGS_LPIPS_MODEL", raising=False)
    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "lpips_vgg.onnx").write_bytes(b"a planted model")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "lpips_vgg.onnx").write_bytes(b"a planted model")
    with pytest.raises(M.LPIPSModelNotFound, match="REINGS_LPIPS_MODEL"):
        M.find_lpips_model()
    (tmp_path / "cache" / "models").mkdir(parents=True)
    real = tmp_path / "cache" / "models" / "lpips_vgg.onnx"
    real.write_bytes(b"the user's model")
    assert M.find_lpips_model() == real
    info = M.lpips_model_info()
    assert info["path"] == str(real.resolve()) and info["sha256"] == hashlib.sha256(b"the user's model").hexdigest()


def test_dtu_soft_mask_rules(rng):
    """DNGaussian / CoR-GS metrics_dtu.py: PSNR over the pixels whose (Pillow-resized) mask is
    exactly 1; SSIM and LPIPS on img * m + (1 - m) with the soft mask itself. Checked against the
    direct float64 formulas."""
    a = rng.uniform(0, 1, (16, 20, 3))
    b = rng.uniform(0, 1, (16, 20, 3))
    m = np.zeros((16, 20))
    m[3:13, 4:16] = 1.0
    m[3:13, 4] = 0.8  # a soft edge column: composited, but not in the masked PSNR
    m[3:13, 15] = 254 / 255
    fg = m == 1.0
    want = -10 * np.log10(((a - b) ** 2)[fg].mean())
    assert M.psnr(a, b, mask=m) == pytest.approx(want, rel=1e-12)
    assert M.psnr(a, b, mask=m) != pytest.approx(M.psnr(a, b, mask=m > 0.5), rel=1e-6)
    ca, cb = a * m[..., None] + (1 - m[..., None]), b * m[..., None] + (1 - m[..., None])
    assert M.ssim(a, b, mask=m) == pytest.approx(M.ssim(ca, cb), abs=1e-12)
    for bad in (m * 2, m - 0.5):
        with pytest.raises(ValueError, match="outside"):
            M.psnr(a, b, mask=bad)
