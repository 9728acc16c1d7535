"""From photos to a video (issue 13): `reings process` on unposed PNGs the test writes from the
procedural scene, then `reings run --holdout none`, `reings render`, `reings export`; the
recovered cameras checked against the scene's true ones (up to a similarity), and bad input."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import reings
from reings.cli import main

pytest.importorskip("pycolmap")
cv2 = pytest.importorskip("cv2")

VIEWS = (3, 7, 11, 15)


def _write_photos(folder, scene, idx):
    """The photos of arc views `idx` (of VIEWS: the scene holds those only)."""
    os.makedirs(folder, exist_ok=True)
    for i in idx:
        u8 = np.clip(np.rint(scene.images[VIEWS.index(i)] * 255), 0, 255).astype(np.uint8)
        cv2.imwrite(os.path.join(folder, f"photo_{i:02d}.png"), u8[..., ::-1])


def _similarity_residual(src, dst) -> float:
    """RMS distance after the best similarity transform src -> dst (Umeyama 1991), relative to
    the spread of dst."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (a ** 2).sum(1).mean()
    res = b - s * a @ R.T
    return float(np.sqrt((res ** 2).sum(1).mean()) / np.sqrt((b ** 2).sum(1).mean()))


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    root = tmp_path_factory.mktemp("photos")
    scene = reings.make_procedural_scene(n_views=20, width=320, height=240, views=VIEWS)
    _write_photos(root / "photos", scene, VIEWS)
    return root, scene


def test_photos_to_video(photos, capsys):
    root, scene = photos
    sc = root / "scene"
    assert main(["process", str(root / "photos"), "--out", str(sc), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "registered 4 of 4 photos" in out and "next: reings run --data" in out
    info = json.loads((sc / "process.json").read_text())
    assert info["registered"] == [f"photo_{i:02d}.png" for i in VIEWS] and info["left_out"] == {}
    assert sorted(os.listdir(sc)) == ["images", "process.json", "sparse"]

    loaded = reings.load_scene(str(sc), dataset="colmap", factor=1)
    assert loaded.names == [f"photo_{i:02d}.png" for i in VIEWS]
    est = np.array([c.center for c in loaded.cameras])
    true = np.array([c.center for c in scene.cameras])  # VIEWS' cameras
    assert _similarity_residual(est, true) < 0.02  # the true camera layout, up to scale and frame

    run = root / "run"
    assert main(["run", "--data", str(sc), "--holdout", "none", "--preset", "quick", "--iterations", "20",
                 "--factor", "1", "--depth-prior", "none", "--no-lpips", "--eval-every", "0", "--quiet",
                 "--out", str(run)]) == 0
    m = json.loads((run / "metrics.json").read_text())
    assert m["views"] == 4 and m["scored_on"] == "train" and m["train_names"] == loaded.names

    video = root / "fly.mp4"
    assert main(["render", str(run), "--path", "spiral", "--frames", "24", "--size", "160x120",
                 "--out", str(video)]) == 0
    from reings.video import read_video

    frames = read_video(video)
    assert len(frames) == 24 and frames[0].shape == (120, 160, 3)
    assert np.mean([f.std() for f in frames]) > 5  # pictures, not a blank screen

    exp = root / "inria"
    assert main(["export", str(run), "--format", "inria", "--out", str(exp)]) == 0
    plyfile = pytest.importorskip("plyfile")
    (ply_path,) = [os.path.join(d, f) for d, _, fs in os.walk(exp / "point_cloud") for f in fs]
    ply = plyfile.PlyData.read(ply_path)
    assert sum(p.name.startswith("f_rest_") for p in ply["vertex"].properties) == 45  # 3 SH bands

    from reings.io.cameras import read_cameras_json
    from reings.io.ply import read_ply

    g = read_ply(run / "gaussians.ply")
    for rec in read_cameras_json(exp / "cameras.json"):
        own = cv2.imread(str(run / "renders" / f"{rec.name}.png"))[..., ::-1].astype(int)
        mine = np.clip(np.rint(reings.render(g, rec.camera).rgb * 255), 0, 255).astype(int)
        assert np.abs(own - mine).max() <= 1


def test_process_refusals_lose_nothing(photos, tmp_path, capsys):
    root, scene = photos
    one = tmp_path / "one"
    _write_photos(one, scene, VIEWS[:1])
    assert main(["process", str(one), "--out", str(tmp_path / "s1"), "--quiet"]) == 2
    assert "structure from motion needs at least 2" in capsys.readouterr().err
    assert not (tmp_path / "s1").exists()

    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "keep.txt").write_text("mine")
    assert main(["process", str(root / "photos"), "--out", str(taken), "--quiet"]) == 2
    assert "not empty" in capsys.readouterr().err and (taken / "keep.txt").read_text() == "mine"

    noise = tmp_path / "noise"
    noise.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):  # unrelated random pictures: nothing to match
        cv2.imwrite(str(noise / f"n{i}.png"), (rng.uniform(0, 255, (60, 80, 3))).astype(np.uint8))
    assert main(["process", str(noise), "--out", str(tmp_path / "s2"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "reings: error:" in err and str(noise) in err
    assert not (tmp_path / "s2").exists()
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".tmp-")]


def test_reconstruct_in_memory_writes_nothing(tmp_path, monkeypatch):
    """No file anywhere: not in the working directory, not in the SfM or depth-prior caches (the
    default stereo prior and the SfM box run; the cache folders must stay empty)."""
    work, cache = tmp_path / "work", tmp_path / "cache"
    work.mkdir()
    cache.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("REINGS_CACHE_DIR", str(cache))
    scene = reings.make_procedural_scene(n_views=3, width=48, height=36, supersample=1)
    g = reings.reconstruct(scene.images, scene.cameras, bounds=scene.bounds, iterations=10)
    assert isinstance(g, reings.Gaussians) and len(g) > 0
    assert os.listdir(work) == []
    assert [str(p) for p in cache.rglob("*")] == []
    g = reings.reconstruct(scene.images, scene.cameras, bounds=scene.bounds, iterations=10, depth_prior="none")
    assert os.listdir(work) == [] and [str(p) for p in cache.rglob("*")] == []
    with pytest.raises(ValueError, match="3 images but 2 cameras"):
        reings.reconstruct(scene.images, scene.cameras[:2])
    with pytest.raises(ValueError, match="outside \\[0, 1\\]"):
        reings.reconstruct([im * 2 for im in scene.images], scene.cameras)
    u8 = [np.rint(im * 255).astype(np.uint8) for im in scene.images]  # uint8 is taken as 0..255
    assert len(reings.reconstruct(u8, scene.cameras, bounds=scene.bounds, iterations=5, depth_prior="none")) > 0


def test_two_photos_make_a_scene(photos, tmp_path, capsys):
    """The fewest views COLMAP can work with: two photos register into a model of two images."""
    root, scene = photos
    two = tmp_path / "two"
    _write_photos(two, scene, VIEWS[:2])
    assert main(["process", str(two), "--out", str(tmp_path / "s"), "--quiet"]) == 0
    assert "registered 2 of 2 photos" in capsys.readouterr().out
    sc = reings.load_scene(str(tmp_path / "s"), dataset="colmap", factor=1)
    assert len(sc) == 2
    d_est = np.linalg.norm(sc.cameras[0].center - sc.cameras[1].center)
    assert d_est > 0  # two distinct poses (the scale of a two-view model is arbitrary)


def test_a_photo_that_does_not_register_is_named(photos, tmp_path, capsys):
    """Four scene photos and one of noise (nothing to match): the error names the noise photo and
    says why, exit 2, no scene written; --partial makes the scene from the four and lists the one
    left out in process.json."""
    root, scene = photos
    mixed = tmp_path / "mixed"
    _write_photos(mixed, scene, VIEWS)
    noise = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    cv2.imwrite(str(mixed / "zz_noise.png"), noise)
    out = tmp_path / "s"
    assert main(["process", str(mixed), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "zz_noise.png" in err and "did not register" in err and "--partial" in err, err
    assert not out.exists()
    assert main(["process", str(mixed), "--out", str(out), "--partial", "--quiet"]) == 0
    info = json.loads((out / "process.json").read_text())
    assert info["registered"] == [f"photo_{i:02d}.png" for i in VIEWS]
    assert list(info["left_out"]) == ["zz_noise.png"] and info["left_out"]["zz_noise.png"]
    assert len(reings.load_scene(str(out), dataset="colmap", factor=1)) == 4
