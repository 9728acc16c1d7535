"""`import reings` stays light: no pyopencl, warp, pycolmap, cv2, onnxruntime, and never torch
(checked in a fresh interpreter). Every name in `reings.__all__` resolves."""
import json
import subprocess
import sys

HEAVY = ("pyopencl", "warp", "pycolmap", "cv2", "onnxruntime", "torch")


def _loaded_after(code: str) -> set:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys, json; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


def test_import_is_light():
    mods = _loaded_after("import reings")
    assert not [m for m in HEAVY if m in mods]


def test_public_names_resolve_without_torch():
    mods = _loaded_after("import reings\nfor n in reings.__all__: getattr(reings, n)")
    assert "torch" not in mods


def test_cli_help():
    r = subprocess.run([sys.executable, "-m", "reings.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "devices" in r.stdout


def test_cli_bad_device_is_a_clear_error():
    r = subprocess.run([sys.executable, "-c", "import reings, numpy as np\n"
                        "g = reings.Gaussians(np.zeros((1,3)), np.array([[1,0,0,0]]), np.zeros((1,3)), np.zeros(1), np.zeros((1,1,3)))\n"
                        "c = reings.Camera(np.diag([10,10,1.0]), np.eye(4), 8, 8)\n"
                        "reings.render(g, c, device='opencl:99:0')"], capture_output=True, text=True)
    assert r.returncode != 0 and "platform 99 does not exist" in r.stderr


def test_devices_lists_pocl():
    r = subprocess.run([sys.executable, "-m", "reings.cli", "devices"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "Portable Computing Language" in r.stdout


def test_no_submodule_shadows_a_public_function():
    """A submodule named like a lazily exported function (say `reings/render.py` next to
    `reings.render`) is bound over that function by the first `from .render import ...`."""
    import importlib.util

    import reings

    clash = [n for n in reings.__all__ if n not in reings._SUBMODULES
             and importlib.util.find_spec(f"reings.{n}") is not None]
    assert not clash
