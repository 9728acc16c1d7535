"""Packaging facts a user relies on (issue 14, items 19 and 20), read from pyproject.toml."""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _extras():
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]["optional-dependencies"]


def test_opencv_is_the_contrib_headless_build():
    """Item 19: the user named opencv-contrib-python-headless; opencv-python-headless installs the
    same cv2 module and conflicts with it."""
    data = _extras()["data"]
    names = [re.split(r"[<>=!~;\[ ]", d, maxsplit=1)[0] for d in data]
    assert "opencv-contrib-python-headless" in names and "opencv-python-headless" not in names


def test_pycolmap_range_is_the_working_one():
    """Item 20: pycolmap 3.12 and 3.13 lack calls reings/data/colmap.py makes; the floor is 4.0
    and the range is capped below the next major."""
    spec = next(d for d in _extras()["data"] if d.startswith("pycolmap"))
    assert ">=4.0" in spec and "<5" in spec, spec


def test_license_and_typing_marker():
    """Item 22 (part): a LICENSE matching pyproject's license, and the PEP 561 marker."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib
    with open(ROOT / "pyproject.toml", "rb") as f:
        proj = tomllib.load(f)["project"]
    assert proj["license"] == {"file": "LICENSE"}
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "License :: OSI Approved :: MIT License" in proj["classifiers"]
    assert (ROOT / "reings" / "py.typed").is_file()


def test_imports_without_posix_only_modules():
    """Item 22 (part): `import resource` at module level kept the package from importing where it
    does not exist (Windows); the pipeline now imports, and reports no peak RSS there."""
    import subprocess
    import sys

    code = ("import sys; sys.modules['resource'] = None; sys.modules['fcntl'] = None\n"
            "import reings, reings.pipeline, reings.evaluate\n"
            "assert reings.pipeline._peak_rss_mb() is None\n"
            "print('ok')")
    p = subprocess.run([sys.executable, "-c", code], cwd=str(ROOT), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "ok" in p.stdout, p.stderr[-2000:]


def test_missing_extras_are_named_before_any_work(tmp_path):
    """Item 21: without the extras, `reings run` trained for minutes and then crashed at
    `import cv2` (renders) or onnxruntime (LPIPS). Now one line names the package, before work."""
    import subprocess
    import sys

    def run(block: str, *args) -> subprocess.CompletedProcess:
        code = (f"import sys; sys.modules[{block!r}] = None\n"
                "from reings.cli import main\n"
                f"sys.exit(main({list(args)!r}))")
        return subprocess.run([sys.executable, "-c", code], cwd=str(ROOT), capture_output=True, text=True,
                              timeout=120)

    out = str(tmp_path / "o")
    p = run("cv2", "run", "--quiet", "--out", out)
    assert p.returncode == 2 and "needs OpenCV" in p.stderr and "reings[data]" in p.stderr, p.stderr[-2000:]
    assert "Traceback" not in p.stderr and not (tmp_path / "o").exists()
    model = ROOT.parent / "shared" / "models" / "lpips_vgg.onnx"
    import os

    if os.environ.get("REINGS_LPIPS_MODEL") or model.is_file():
        p = run("onnxruntime", "run", "--quiet", "--out", out)
        assert p.returncode == 2 and "LPIPS needs onnxruntime" in p.stderr and "--no-lpips" in p.stderr, p.stderr[-2000:]


def test_cache_dir_follows_the_platform(monkeypatch, tmp_path):
    """$REINGS_CACHE_DIR first, else platformdirs' user cache folder (on Linux: $XDG_CACHE_HOME)."""
    import platformdirs

    from reings.io.files import cache_dir

    monkeypatch.setenv("REINGS_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_dir("depth") == tmp_path / "mine" / "depth"
    monkeypatch.delenv("REINGS_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir("sfm") == Path(platformdirs.user_cache_dir("reings", appauthor=False)) / "sfm"
    if sys.platform.startswith("linux"):
        assert cache_dir("sfm") == tmp_path / "xdg" / "reings" / "sfm"


def test_run_lock_is_exclusive_across_processes(tmp_path):
    """reings eval's per-run lock (fcntl on POSIX, msvcrt on Windows): a second process cannot take it."""
    import subprocess

    from reings.evaluate import RunLock

    lock = RunLock(str(tmp_path / "run"))
    assert lock.acquire()
    code = ("import sys; from reings.evaluate import RunLock; "
            f"sys.exit(0 if not RunLock({str(tmp_path / 'run')!r}).acquire() else 1)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
    lock.release()
    code = code.replace("0 if not", "0 if")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
