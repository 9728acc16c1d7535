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


ENGINE_MODULES = ("train", "densify", "state", "optim", "losses", "pipeline", "evaluate")


def _imports(path) -> set:
    """Absolute module names imported anywhere in a file of the reings package (lazy imports too)."""
    import ast
    import pathlib

    rel = pathlib.Path(path).relative_to(pathlib.Path(__file__).resolve().parents[1])
    pkg = list(rel.with_suffix("").parts[:-1])
    if rel.name == "__init__.py":
        pkg = list(rel.parent.parts)
    out = set()
    for node in ast.walk(ast.parse(pathlib.Path(path).read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = pkg[: len(pkg) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)  # `from . import losses`
    return out


def test_layering():
    """Backends own every kernel's host code and import no engine module; nothing outside
    reings/backends/ imports pyopencl (issue 11)."""
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1] / "reings"
    bad = []
    for p in sorted(root.rglob("*.py")):
        mods = _imports(p)
        in_backends = "backends" in p.relative_to(root).parts
        if not in_backends and any(m == "pyopencl" or m.startswith("pyopencl.") for m in mods):
            bad.append(f"{p.relative_to(root)} imports pyopencl")
        if in_backends:
            bad += [f"{p.relative_to(root)} imports {m}" for m in sorted(mods)
                    if any(m == f"reings.{e}" or m.startswith(f"reings.{e}.") for e in ENGINE_MODULES)]
    assert not bad, bad
