"""Fly-through rendering (reings.video, backend `render_frames`), videos, `reings render` and
`reings export`, on a small model and a finished tiny run."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import reings
from reings.cli import main
from reings.paths import look_at

pytest.importorskip("cv2")


def _model(n=300, seed=0, sh_degree=1):
    rng = np.random.default_rng(seed)
    k = (1, 4, 9, 16)[sh_degree]
    return reings.Gaussians(means=rng.uniform([-1, -1, 3], [1, 1, 6], (n, 3)),
                            quats=rng.normal(size=(n, 4)), log_scales=rng.uniform(-3.5, -2.0, (n, 3)),
                            opacity_logits=rng.uniform(-1, 3, n), sh=rng.normal(0, 0.5, (n, k, 3)))


def _cams(n=3, w=40, h=30):
    K = np.array([[40.0, 0, w / 2], [0, 40.0, h / 2], [0, 0, 1]])
    return [look_at(np.array([x, 0.0, 0.0]), np.array([0.0, 0.0, 4.5]), np.array([0, -1.0, 0]), K, w, h)
            for x in np.linspace(-0.3, 0.3, n)]


def test_render_frames_equals_render(device):  # every OpenCL test device (conftest)
    _check_render_frames(device)


def test_render_frames_equals_render_reference():
    _check_render_frames("reference")


def _check_render_frames(device):
    from reings.backends import get_backend

    g, cams = _model(), _cams()
    be = get_backend(device)
    got = list(be.render_frames(g, cams, background=(0.125, 0.25, 0.375), near=0.01, depth=True))
    assert len(got) == len(cams)
    for (rgb, d), cam in zip(got, cams):
        ref = reings.render(g, cam, device=device, background=(0.125, 0.25, 0.375))
        np.testing.assert_array_equal(rgb, ref.rgb)
        np.testing.assert_array_equal(d, ref.depth)
    (rgb, d), = be.render_frames(g, cams[:1])
    assert d is None and rgb.shape == (30, 40, 3)


def test_video_round_trip(tmp_path):
    from reings.video import read_video, write_video

    rng = np.random.default_rng(1)
    base = (rng.uniform(0, 255, (6, 8, 3))).astype(np.uint8)
    frames = [np.kron(np.roll(base, i, axis=1), np.ones((8, 8, 1), np.uint8)) for i in range(12)]  # 64x48
    for ext in (".mp4", ".avi"):
        p = write_video(tmp_path / f"v{ext}", frames, fps=10)
        back = read_video(p)
        assert len(back) == 12 and back[0].shape == (48, 64, 3)
        err = np.mean([np.abs(a.astype(float) - b).mean() for a, b in zip(back, frames)])
        assert err < 12, err  # lossy codecs, but the same pictures
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".tmp-")]
    with pytest.raises(ValueError, match="unknown video extension"):
        write_video(tmp_path / "v.gif", frames)
    with pytest.raises(ValueError, match="frame 1 is"):
        write_video(tmp_path / "w.mp4", [frames[0], frames[0][:40]])
    assert not os.path.exists(tmp_path / "w.mp4")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A finished run of the in-memory procedural scene, every view trained (--holdout none)."""
    out = tmp_path_factory.mktemp("run") / "r"
    scene = reings.make_procedural_scene(n_views=4, width=48, height=36, supersample=1)
    r = reings.run(scene=scene, holdout="none", method="dngaussian", iterations=30, depth_prior="exact",
                   out=str(out), quiet=True, with_lpips=False, eval_every=0)
    return out, scene, r


def test_holdout_none_trains_every_view_and_scores_them(tiny_run):
    out, scene, r = tiny_run
    m = json.loads((out / "metrics.json").read_text())
    assert m["views"] == 4 and m["holdout"] == "none" and m["scored_on"] == "train"
    assert m["train_indices"] == [0, 1, 2, 3] and m["test_indices"] == [0, 1, 2, 3]
    assert m["data"] == "in-memory" and sorted(os.listdir(out / "renders")) == [f"view00{i}.png" for i in range(4)]


def test_cameras_json_reproduces_the_training_views(tiny_run):
    """Rendering through cameras.json gives the run's own renders."""
    import cv2

    from reings.io.cameras import read_cameras_json

    out, scene, r = tiny_run
    recs = read_cameras_json(out / "cameras.json")
    assert [x.name for x in recs] == ["view000", "view001", "view002", "view003"]
    assert {x.split for x in recs} == {"train"}
    from reings.io.ply import read_ply

    g = read_ply(out / "gaussians.ply")
    for rec, cam in zip(recs, scene.cameras):
        np.testing.assert_allclose(rec.camera.viewmat, cam.viewmat, atol=1e-12)
        own = cv2.imread(str(out / "renders" / f"{rec.name}.png"))[..., ::-1].astype(int)
        mine = np.clip(np.rint(reings.render(g, rec.camera).rgb * 255), 0, 255).astype(int)
        assert np.abs(own - mine).max() <= 1


def test_reings_render_writes_the_requested_video(tiny_run, tmp_path, capsys):
    from reings.video import read_video

    out, _, _ = tiny_run
    v, d, fr = tmp_path / "fly.mp4", tmp_path / "depth.mp4", tmp_path / "frames"
    assert main(["render", str(out), "--path", "spiral", "--frames", "24", "--size", "64x48", "--out", str(v),
                 "--depth-out", str(d), "--frames-dir", str(fr)]) == 0
    assert "rendered 24 frames 64x48 (spiral)" in capsys.readouterr().out
    back = read_video(v)
    assert len(back) == 24 and back[0].shape == (48, 64, 3)
    assert len(read_video(d)) == 24 and len(os.listdir(fr)) == 24
    for path in ("ellipse", "interpolate"):
        assert main(["render", str(out), "--path", path, "--frames", "5", "--out", str(tmp_path / f"{path}.avi")]) == 0
    # --cameras renders the given cameras as they are: the training view's own render
    assert main(["render", str(out), "--cameras", str(out / "cameras.json"), "--frames-dir", str(tmp_path / "c")]) == 0
    import cv2

    a = cv2.imread(str(tmp_path / "c" / "frame_0000.png")).astype(int)
    b = cv2.imread(str(out / "renders" / "view000.png")).astype(int)
    assert np.abs(a - b).max() <= 1


@pytest.mark.parametrize("argv, msg", [
    (["--frames", "0", "--out", "x.mp4"], "--frames must be >= 1"),
    (["--size", "64by48", "--out", "x.mp4"], "expected WIDTHxHEIGHT"),
    (["--out", "x.gif"], "unknown video extension"),
    (["--background", "2,0,0", "--out", "x.mp4"], "R,G,B in \\[0, 1\\]"),
    ([], "nothing to write"),
])
def test_reings_render_bad_input(tiny_run, tmp_path, capsys, argv, msg):
    import re

    out, _, _ = tiny_run
    argv = [a if a != "x.mp4" and a != "x.gif" else str(tmp_path / a) for a in argv]
    assert main(["render", str(out), *argv]) == 2
    assert re.search(msg, capsys.readouterr().err)
    assert os.listdir(tmp_path) == []


def test_reings_render_refuses_what_is_not_a_run(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "v.mp4")]) == 2
    assert "run folder not found" in capsys.readouterr().err
    (tmp_path / "r").mkdir()
    assert main(["render", str(tmp_path / "r"), "--out", str(tmp_path / "v.mp4")]) == 2
    assert "no gaussians.ply" in capsys.readouterr().err


def test_reings_export_ply_and_inria(tiny_run, tmp_path):
    plyfile = pytest.importorskip("plyfile")
    from reings.io.ply import read_ply

    out, _, r = tiny_run
    assert main(["export", str(out), "--out", str(tmp_path / "p")]) == 0
    ply = plyfile.PlyData.read(str(tmp_path / "p" / "point_cloud.ply"))
    names = [p.name for p in ply["vertex"].properties]
    assert sum(n.startswith("f_rest_") for n in names) == 45  # 3 bands x 3 colours x 15 coefficients
    assert any("reings" in c and "method=dngaussian" in c for c in ply.comments)
    g0, g3 = read_ply(out / "gaussians.ply"), read_ply(tmp_path / "p" / "point_cloud.ply")
    np.testing.assert_array_equal(g3.sh[:, :g0.sh.shape[1]], g0.sh)
    assert not g3.sh[:, g0.sh.shape[1]:].any()
    np.testing.assert_array_equal(np.asarray(ply["vertex"]["x"]), g0.means[:, 0])
    # same folder again: refused without --overwrite, nothing changed
    assert main(["export", str(out), "--out", str(tmp_path / "p")]) == 2
    assert main(["export", str(out), "--out", str(tmp_path / "p"), "--overwrite", "--sh-degree", "0"]) == 0

    assert main(["export", str(out), "--format", "inria", "--out", str(tmp_path / "i")]) == 0
    its = os.listdir(tmp_path / "i" / "point_cloud")
    assert its == ["iteration_30"]
    ply = plyfile.PlyData.read(str(tmp_path / "i" / "point_cloud" / its[0] / "point_cloud.ply"))
    assert sum(p.name.startswith("f_rest_") for p in ply["vertex"].properties) == 45
    cams = json.loads((tmp_path / "i" / "cameras.json").read_text())
    assert len(cams) == 4 and set(cams[0]) >= {"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"}
    assert (tmp_path / "i" / "cfg_args").read_text().startswith("Namespace(") and "sh_degree=3" in \
        (tmp_path / "i" / "cfg_args").read_text()


def test_no_codec_is_said_before_rendering(tiny_run, tmp_path, capsys, monkeypatch):
    """A machine whose OpenCV cannot encode the extension: one line naming the file and the codec,
    exit 1, before any frame is rendered (render_path is never called), no file or temp left."""
    import cv2

    import reings.video as V

    class Closed:  # a VideoWriter that could not open the codec
        def __init__(self, *a, **k):
            pass

        def isOpened(self):
            return False

        def release(self):
            pass

    def no_render(*a, **k):
        raise AssertionError("rendered before the codec was checked")

    monkeypatch.setattr(cv2, "VideoWriter", Closed)
    monkeypatch.setattr(V, "render_path", no_render)
    out, _, _ = tiny_run
    v = tmp_path / "fly.mp4"
    assert main(["render", str(out), "--frames", "4", "--out", str(v)]) == 1
    err = capsys.readouterr().err
    assert "fly.mp4" in err and "cannot encode .mp4 (mp4v)" in err and "--frames-dir" in err, err
    assert "Traceback" not in err and os.listdir(tmp_path) == []
