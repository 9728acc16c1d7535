"""Packaging facts a user relies on (issue 14, items 19 and 20), read from pyproject.toml."""
from __future__ import annotations

import re
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
