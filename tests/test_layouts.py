"""Layouts and constants written twice, once in Python and once in OpenCL C, checked against each other.

The C side is read from `kernels/` as text: object-like `#define`s (with the `#include`s of a file
followed, C literals typed: `1e-4f` is a float32, `0.2` a double, `16` an int) and the layout
comments that are the only statement of a record's field order (the camera record in
`project.cl`, the gradient record in `rasterize.cl`, the `grad_mask` bits). The Python side is
the package's own values: module-level constants found by name anywhere in `reings/` (every
definition of the name must agree, so a second copy cannot drift either), `camera_record`, and
the slicing and packing of the gradient record read from the source with `ast`.

A check that finds nothing to compare (a name, a comment or a call that has been renamed) fails
and says what it looked for: it never passes vacuously.
"""
from __future__ import annotations

import ast
import importlib
import re
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
KERNELS = ROOT / "kernels"
PACKAGE = ROOT / "reings"

# {{{ reading C


def _strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)  # keep line numbers
    return re.sub(r"//[^\n]*", "", text)


@lru_cache(maxsize=None)
def c_text(name: str) -> str:
    return (KERNELS / name).read_text(encoding="utf-8")


@lru_cache(maxsize=None)
def c_defines(name: str) -> dict[str, list[str]]:
    """Object-like `#define NAME value` of kernels/`name` and the files it `#include`s (theirs
    first), as NAME -> every value text seen (a name may be defined on several `#if` branches)."""
    text = c_text(name)
    out: dict[str, list[str]] = {}
    for inc in re.findall(r'^\s*#\s*include\s+"([^"]+)"', text, flags=re.M):
        for k, v in c_defines(inc).items():
            out.setdefault(k, []).extend(v)
    body = _strip_comments(text).replace("\\\n", " ")
    for m in re.finditer(r"^\s*#\s*define\s+(\w+)(?!\()[ \t]*([^\n]*)$", body, flags=re.M):
        vals = out.setdefault(m.group(1), [])
        if m.group(2).strip() not in vals:
            vals.append(m.group(2).strip())
    return out


_LITERAL = re.compile(r"\b(0[xX][0-9A-Fa-f]*\.?[0-9A-Fa-f]*[pP][-+]?\d+|0[xX][0-9A-Fa-f]+|"
                      r"(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?)([fFuUlL]*)\b|"
                      r"(?<![\w.])(\.\d+(?:[eE][-+]?\d+)?)([fF]?)")
_CAST = re.compile(r"\(\s*(?:real|float|double|int|uint|unsigned int|unsigned)\s*\)")


def c_eval(expr: str, file: str, _depth: int = 0):
    """Value of a C constant expression over the defines visible in kernels/`file`: int for
    integer literals, np.float32 for `f`-suffixed ones, float (double) otherwise. Casts to
    float/real/double/int types are dropped (the values here are exact in every such type)."""
    if _depth > 20:
        raise ValueError(f"{file}: define recursion in {expr!r}")
    lits: dict[str, object] = {}

    def lit(m):
        text, suffix = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
        if text.lower().startswith("0x") and "p" in text.lower():  # hexadecimal float
            val = np.float32(float.fromhex(text)) if "f" in suffix.lower() else float.fromhex(text)
        elif text.lower().startswith("0x"):
            val = int(text, 16)
        elif re.fullmatch(r"\d+", text) and "f" not in suffix.lower():
            val = int(text)
        else:
            val = np.float32(text) if "f" in suffix.lower() else float(text)
        key = f"__lit{len(lits)}"
        lits[key] = val
        return key

    py = _LITERAL.sub(lit, _CAST.sub("", expr))
    defs = c_defines(file)

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Name):
            if node.id in lits:
                return lits[node.id]
            vals = defs.get(node.id)
            if not vals:
                raise KeyError(f"{file}: {node.id} is not #defined (in {expr!r})")
            if len(vals) > 1:
                raise ValueError(f"{file}: {node.id} has several definitions {vals}")
            return c_eval(vals[0], file, _depth + 1)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            v = ev(node.operand)
            return -v if isinstance(node.op, ast.USub) else v
        if isinstance(node, ast.BinOp):
            a, b = ev(node.left), ev(node.right)
            ops = {ast.Add: lambda: a + b, ast.Sub: lambda: a - b, ast.Mult: lambda: a * b,
                   ast.LShift: lambda: a << b, ast.RShift: lambda: a >> b,
                   ast.BitOr: lambda: a | b, ast.BitAnd: lambda: a & b,
                   ast.Div: lambda: int(a / b) if isinstance(a, int) and isinstance(b, int) else a / b}
            if type(node.op) in ops:
                return ops[type(node.op)]()
        raise ValueError(f"{file}: cannot evaluate {expr!r} ({ast.dump(node)[:80]})")

    return ev(ast.parse(py.strip(), mode="eval"))


def c_value(file: str, name: str):
    vals = c_defines(file).get(name)
    assert vals, f"kernels/{file}: no `#define {name}` (renamed? update tests/test_layouts.py)"
    assert len(vals) == 1, f"kernels/{file}: {name} is defined {len(vals)} ways: {vals}"
    return c_eval(vals[0], file)


def same_value(c, py) -> bool:
    """C value == Python value at the C literal's precision."""
    if isinstance(c, np.float32):
        return np.float32(py) == c
    if isinstance(c, float):
        return float(py) == c
    return isinstance(py, (int, np.integer)) and int(py) == c


# }}}

# {{{ reading Python


@lru_cache(maxsize=None)
def _py_files():
    out = []
    for p in sorted(PACKAGE.rglob("*.py")):
        rel = p.relative_to(ROOT)
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out.append((".".join(parts), rel, ast.parse(p.read_text(encoding="utf-8"))))
    return out


def py_definitions(name: str) -> list[tuple[str, object]]:
    """(module, value) of every module-level assignment `name = ...` in reings/ (imported to
    read the value as Python computes it)."""
    found = []
    for mod, rel, tree in _py_files():
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, ast.AnnAssign) else []
            names = [t.id for t in targets if isinstance(t, ast.Name)]
            names += [e.id for t in targets if isinstance(t, ast.Tuple) for e in t.elts if isinstance(e, ast.Name)]
            if name in names:
                found.append((mod, getattr(importlib.import_module(mod), name)))
                break
    assert found, f"no module-level `{name} = ...` in reings/ (renamed? update tests/test_layouts.py)"
    return found


def py_function(name: str):
    """The one module-level function `name` of reings/ (imported)."""
    mods = [mod for mod, _, tree in _py_files()
            for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == name]
    assert len(mods) == 1, f"expected one module-level def {name} in reings/, found it in {mods}"
    return getattr(importlib.import_module(mods[0]), name)


def py_calls(func_name: str):
    """(file, Call node) of every call of `func_name` (plain or attribute) in reings/."""
    for _, rel, tree in _py_files():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                n = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
                if n == func_name:
                    yield rel, node


# }}}

# {{{ constants

# (kernel file, C expression, Python name, index into the Python value or None, what it is)
CONSTANTS = [
    ("common.h", "TILE_SIZE", "TILE_SIZE", None, "tile side in pixels"),
    ("common.h", "TILE_PIXELS", "TILE_PIXELS", None, "pixels per tile"),
    ("common.h", "ALPHA_MIN", "ALPHA_MIN", None, "skip a pair below this alpha"),
    ("common.h", "ALPHA_MAX", "ALPHA_MAX", None, "alpha clamp"),
    ("common.h", "T_MIN", "T_MIN", None, "transmittance stop"),
    ("common.h", "EPS2D", "EPS2D", None, "2D low-pass dilation"),
    ("common.h", "CLAMP_GUARD", "CLAMP_GUARD", None, "Jacobian guard band"),
    ("common.h", "V_RECORD", "V_RECORD", None, "floats per gradient record"),
    ("project.cl", "V_PROJ", "V_RECORD", None, "width of the v_proj record project_bwd reads"),
    ("densify_accumulate.cl", "V_PROJ", "V_RECORD", None, "width of the v_proj record densify_accumulate.cl reads"),
    ("densify.h", "V_PROJ", "V_RECORD", None, "width of the v_proj record densify.h reads (unless its includer set it)"),
    ("project.cl", "PROJ_EPS2D", "EPS2D", None, "projection's dilation"),
    ("project.cl", "CAM_RECORD", "CAM_RECORD", None, "floats per camera record"),
    ("project.cl", "DEPTH_KEY_CULLED", "DEPTH_KEY_CULLED", None, "sort key of a culled Gaussian"),
    ("bin.cl", "DEPTH_KEY_CULLED", "DEPTH_KEY_CULLED", None, "sort key of a culled Gaussian"),
    ("project.cl", "PROJ_LAMBDA_FLOOR", "LAMBDA_FLOOR", None, "eigenvalue spread floor"),
    ("project.cl", "PROJ_QUAT_NORM_MIN", "QUAT_NORM_MIN", None, "quaternion norm cull"),
    ("common.h", "ALPHA_BOX_REL", "ALPHA_BOX_REL", None, "alpha box: relative room"),
    ("common.h", "ALPHA_BOX_PAD", "ALPHA_BOX_PAD", None, "alpha box: room in pixels"),
    ("project.cl", "PROJ_BOX_SLACK", "BOX_SLACK", None, "opacity-aware rect: extra room"),
    ("project.cl", "PROJ_BOX_COND", "BOX_COND", None, "opacity-aware rect: conditioning limit"),
    ("project.cl", "PROJ_BOX_AC_MIN", "BOX_AC_MIN", None, "opacity-aware rect: smallest A C"),
    ("project.cl", "DROP_KEY_MUL", "DROP_KEY_MUL", None, "DropGaussian mask hash: key multiplier"),
    ("project.cl", "DROP_FMIX_MUL1", "DROP_FMIX_MUL1", None, "DropGaussian mask hash: fmix32 constant"),
    ("project.cl", "DROP_FMIX_MUL2", "DROP_FMIX_MUL2", None, "DropGaussian mask hash: fmix32 constant"),
    ("project.cl", "SH_C0", "SH_C0", None, "SH constant"),
    ("project.cl", "SH_C1", "SH_C1", None, "SH constant"),
    *[("project.cl", f"SH_C2_{i}", "SH_C2", i, "SH constant") for i in range(5)],
    *[("project.cl", f"SH_C3_{i}", "SH_C3", i, "SH constant") for i in range(7)],
    ("photometric.cl", "SSIM_C1", "SSIM_C1", None, "SSIM stabiliser"),
    ("photometric.cl", "SSIM_C2", "SSIM_C2", None, "SSIM stabiliser"),
    ("photometric.cl", "2 * SSIM_R + 1", "SSIM_WINDOW", None, "SSIM window taps"),
]


@pytest.mark.parametrize("file,c_expr,py_name,index,what", CONSTANTS,
                         ids=[f"{c[0]}:{c[1].replace(' ', '')}" for c in CONSTANTS])
def test_constant_matches(file, c_expr, py_name, index, what):
    c = c_eval(c_expr, file)
    defs = py_definitions(py_name)
    first_mod, first = defs[0]
    for mod, val in defs[1:]:  # Python copies agree exactly (not only at the C literal's precision)
        assert np.array_equal(np.asarray(val), np.asarray(first)), f"{mod}.{py_name} = {val!r} but {first_mod}.{py_name} = {first!r}"
    for mod, val in defs:
        v = val if index is None else val[index]
        assert same_value(c, v), (f"{what}: kernels/{file} {c_expr} = {c!r} but {mod}.{py_name}"
                                  f"{'' if index is None else f'[{index}]'} = {v!r}")


def test_opacity_split_matches_regularize_cl():
    """regularize.cl's OPA_SPLIT is the default `split` of the opacity penalty (`opacity_reg`)."""
    c = c_value("regularize.cl", "OPA_SPLIT")
    fn = py_function("opacity_reg")
    import inspect

    default = inspect.signature(fn).parameters["split"].default
    assert same_value(c, default), f"kernels/regularize.cl OPA_SPLIT = {c!r}, {fn.__module__}.opacity_reg split = {default!r}"


# }}}

# {{{ camera record


def _camera_comment() -> list[tuple[int, int, str]]:
    """(first, last, field) of the camera record comment in project.cl."""
    text = c_text("project.cl")
    m = re.search(r"/\*\s*Camera record[^*]*?:(.*?)\*/", text, flags=re.S)
    assert m, "kernels/project.cl: no /* Camera record ...: [0..8] ... */ comment"
    fields = []
    for lo, hi, name in re.findall(r"\[(\d+)(?:\.\.(\d+))?\]\s*([^,\[]+)", m.group(1)):
        fields.append((int(lo), int(hi or lo), name.strip()))
    return fields


def _camera_expected(cam, near, guard):
    """Each commented field's value, computed here from the camera (float64)."""
    V, W, H = cam.viewmat, cam.width, cam.height
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy  # gsplat persp_proj: limits = frustum + guard * tan(fov/2)
    return {
        "Rc row-major": V[:3, :3].ravel(), "tc": V[:3, 3], "fx": fx, "fy": fy, "cx": cx, "cy": cy,
        "camera centre": -V[:3, :3].T @ V[:3, 3], "near": near,
        "lim_x_pos": (W - cx) / fx + guard * tan_x, "lim_x_neg": cx / fx + guard * tan_x,
        "lim_y_pos": (H - cy) / fy + guard * tan_y, "lim_y_neg": cy / fy + guard * tan_y,
    }


def test_camera_record_matches_project_cl():
    from reings.types import Camera

    fields = _camera_comment()
    size = c_value("project.cl", "CAM_RECORD")
    covered = [i for lo, hi, _ in fields for i in range(lo, hi + 1)]
    assert covered == list(range(size)), f"project.cl camera comment covers {covered}, CAM_RECORD = {size}"

    # a camera with no symmetric values: a rotation about a skew axis, off-centre principal point
    ax = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    ang = 0.7
    Kx = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
    R = np.eye(3) + np.sin(ang) * Kx + (1 - np.cos(ang)) * Kx @ Kx
    V = np.eye(4)
    V[:3, :3], V[:3, 3] = R, (0.4, -1.3, 2.9)
    cam = Camera(np.array([[311.0, 0, 97.3], [0, 287.0, 61.9], [0, 0, 1]]), V, 203, 151)
    near = 0.037
    (guard,) = {v for _, v in py_definitions("CLAMP_GUARD")}
    rec = np.asarray(py_function("camera_record")(cam, near))
    (py_size,) = {v for _, v in py_definitions("CAM_RECORD")}
    assert rec.shape == (size,) == (py_size,), f"camera_record gives {rec.shape}, CAM_RECORD C {size} / Python {py_size}"
    assert rec.dtype == np.float32, rec.dtype
    want = _camera_expected(cam, near, guard)
    for lo, hi, name in fields:
        assert name in want, f"project.cl camera field {name!r} unknown to this test: add its value in _camera_expected"
        exp = np.asarray(want[name], np.float64).ravel()
        assert exp.size == hi - lo + 1, f"camera field {name!r}: comment gives {hi - lo + 1} floats, expected {exp.size}"
        np.testing.assert_array_equal(rec[lo:hi + 1], exp.astype(np.float32),
                                      err_msg=f"camera_record[{lo}:{hi + 1}] is not {name!r} (project.cl comment)")


def test_project_cl_reads_the_camera_record_as_commented():
    """The scalar reads `name = cam[k]` and the clamp / centre reads of project.cl use the
    commented indices (the comment is what the Python side is checked against)."""
    idx = {}
    for lo, hi, name in _camera_comment():
        for i in range(lo, hi + 1):
            idx[i] = name
    src = _strip_comments(c_text("project.cl"))
    size = c_value("project.cl", "CAM_RECORD")
    used = [int(k) for k in re.findall(r"\bcam\[(\d+)\]", src)]
    assert used, "project.cl: no cam[k] reads found (renamed? update tests/test_layouts.py)"
    assert max(used) < size, f"project.cl reads cam[{max(used)}], CAM_RECORD = {size}"
    scalar = dict((v, int(k)) for v, k in re.findall(r"\b(near|fx|fy|cx|cy)\s*=\s*cam\[(\d+)\]", src))
    assert set(scalar) == {"near", "fx", "fy", "cx", "cy"}, f"project.cl scalar camera reads found: {scalar}"
    for var, k in scalar.items():
        assert idx[k] == var, f"project.cl reads {var} from cam[{k}], the comment says cam[{k}] is {idx[k]!r}"
    # clamp, or VCLAMP (project.cl's lanes: fmin(fmax) without PoCL's library calls, docs/perf_notes.md §35)
    clamps = re.findall(r"\b(?:clamp|VCLAMP)\(\s*(\w)z\s*,\s*-cam\[(\d+)\]\s*,\s*cam\[(\d+)\]\s*\)", src)
    assert {a for a, _, _ in clamps} == {"x", "y"}, f"project.cl clamp reads found: {clamps}"
    for axis, neg, pos in clamps:
        assert (idx[int(neg)], idx[int(pos)]) == (f"lim_{axis}_neg", f"lim_{axis}_pos"), (axis, neg, pos)
    centre = re.findall(r"mu\[(\d)\]\s*-\s*cam\[(\d+)\]", src)
    assert len(centre) == 3 and all(idx[int(k)] == "camera centre" and int(k) - min(int(c) for _, c in centre) == int(j)
                                    for j, k in centre), f"project.cl centre reads: {centre}"


# }}}

# {{{ the gradient record [N, V_RECORD] (rasterize_bwd writes, isect_reduce sums, project_bwd reads)

# the record's scalar names in rasterize.cl's comment -> (RasterGrads field, component or None)
RECORD_FIELDS = {"v_u": ("v_means2d", 0), "v_v": ("v_means2d", 1), "v_A": ("v_conics", 0),
                 "v_B": ("v_conics", 1), "v_C": ("v_conics", 2), "v_r": ("v_colors", 0),
                 "v_g": ("v_colors", 1), "v_b": ("v_colors", 2), "v_opacity": ("v_opacities", None),
                 "v_z": ("v_depths", None)}
# project_bwd's local names for the same scalars
PROJECT_BWD_NAMES = {"v_u": "v_u", "v_v": "v_v", "v_A": "v_A", "v_B": "v_B", "v_C": "v_C", "v_op": "v_opacity",
                     "v_depth": "v_z"}


def _record_order() -> list[str]:
    m = re.search(r"v_emit\[emit, V_RECORD\]\s*=\s*\*?\s*\(([^)]*)\)", c_text("rasterize.cl"))
    assert m, "kernels/rasterize.cl: no `v_emit[emit, V_RECORD] = (v_u, ...)` comment"
    order = [s.strip(" *\n") for s in m.group(1).replace("\n", " ").split(",")]
    order = [re.sub(r"\s+\*\s*", "", s).strip() for s in order]
    assert sorted(order) == sorted(RECORD_FIELDS), f"rasterize.cl record names {order}"
    return order


def _field_slices() -> dict[str, tuple[int, int]]:
    """RasterGrads field -> [start, stop) in the record, from rasterize.cl's order."""
    out: dict[str, list[int]] = {}
    for pos, name in enumerate(_record_order()):
        out.setdefault(RECORD_FIELDS[name][0], []).append(pos)
    for f, pos in out.items():
        assert pos == list(range(pos[0], pos[-1] + 1)), f"record field {f} is not contiguous: {pos}"
    return {f: (p[0], p[-1] + 1) for f, p in out.items()}


def test_record_width_is_the_comment_length():
    assert len(_record_order()) == c_value("common.h", "V_RECORD")


def test_project_bwd_reads_the_record_in_rasterize_order():
    order = _record_order()
    src = _strip_comments(c_text("project.cl"))
    reads = {PROJECT_BWD_NAMES[n]: int(k) for n, k in re.findall(r"\b(v_\w+)\s*=\s*vin\[(\d+)\]", src)
             if n in PROJECT_BWD_NAMES}
    col = re.search(r"v_col\[3\]\s*=\s*\{\s*vin\[(\d+)\]\s*,\s*vin\[(\d+)\]\s*,\s*vin\[(\d+)\]\s*\}", src)
    assert col, "project.cl: no `v_col[3] = {vin[a], vin[b], vin[c]}`"
    reads.update(zip(("v_r", "v_g", "v_b"), map(int, col.groups())))
    assert reads == {n: i for i, n in enumerate(order)}, f"project_bwd reads {reads}, rasterize.cl writes {order}"


def test_rasterize_bwd_writes_the_record_in_comment_order():
    """The CPU schedule's `o[k] = hsum(a_<x>)` and the GPU schedule's per-channel `ACC(k, v<x>[q] * ...)`
    (vals[k], summed over a work-item's BWD_PIX pixels) store each scalar at its commented position."""
    order = {n: i for i, n in enumerate(_record_order())}
    src = _strip_comments(c_text("rasterize.cl"))
    cpu = {f"v_{x}": int(k) for k, x in re.findall(r"\bo\[(\d+)\]\s*=\s*hsum\(a_(\w+)\)", src)}
    cpu = {{"v_o": "v_opacity"}.get(n, n): k for n, k in cpu.items()}
    assert cpu == order, f"rasterize.cl CPU writer: {cpu}, comment order {order}"
    gpu_names = {"vr": "v_r", "vg": "v_g", "vb": "v_b", "vd": "v_z", "va": "v_opacity"}
    gpu = {gpu_names[x]: int(k) for k, x in re.findall(r"\bACC\((\d+),\s*(v[rgbda])\b", src)}
    assert set(gpu) == set(gpu_names.values()), f"rasterize.cl GPU writer: found {gpu}"
    assert all(order[n] == k for n, k in gpu.items()), f"rasterize.cl GPU writer: {gpu}, comment order {order}"


def test_densify_accumulate_reads_means2d_gradient_from_the_record():
    """The densification statistic (densify.h, run by densify_accumulate.cl and by project_bwd with stats)
    reads v_proj[i*V_PROJ + 0 / + 1] as the 2D mean gradient; both kernel files take it from there."""
    src = _strip_comments(c_text("densify.h"))
    offs = [int(o or 0) for o in re.findall(r"v_proj\[\(size_t\)i \* V_PROJ(?: \+ (\d+))?\]", src)]
    assert offs, "densify.h: no v_proj[(size_t)i * V_PROJ + k] reads"
    a, b = _field_slices()["v_means2d"]
    assert sorted(offs) == list(range(a, b)), f"densify.h reads offsets {offs}, v_means2d is [{a}, {b})"
    for name in ("densify_accumulate.cl", "project.cl"):
        text = _strip_comments(c_text(name))
        assert '#include "densify.h"' in text and "densify_accumulate_one(" in text, name


def _slice_of(node) -> tuple[int, int] | None:
    """`x[:, a:b]` -> (a, b), `x[:, k]` -> (k, k + 1), through a trailing `.copy()`; else None."""
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "copy":
        node = node.func.value
    if not (isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Tuple) and len(node.slice.elts) == 2):
        return None
    s = node.slice.elts[1]
    if isinstance(s, ast.Slice) and isinstance(s.lower, ast.Constant) and isinstance(s.upper, ast.Constant):
        return s.lower.value, s.upper.value
    if isinstance(s, ast.Constant):
        return s.value, s.value + 1
    return None


def test_python_unpacks_the_record_in_rasterize_order():
    """Every `RasterGrads(v_means2d=v[:, 0:2], ...)` built from a record slices it as rasterize.cl writes it."""
    want = _field_slices()
    seen = 0
    for rel, call in py_calls("RasterGrads"):
        got = {k.arg: _slice_of(k.value) for k in call.keywords}
        if not any(got.values()):
            continue  # built from separate arrays, not from a record
        seen += 1
        assert got == want, f"{rel}:{call.lineno} unpacks the record as {got}, rasterize.cl order gives {want}"
    assert seen, "no RasterGrads(... = v[:, a:b]) unpacking found in reings/ (renamed? update this test)"


def test_python_packs_the_record_in_rasterize_order():
    """Every `concatenate([grads.v_means2d..reshape(n, 2), ...])` packs the fields in rasterize.cl order."""
    want = sorted(_field_slices().items(), key=lambda kv: kv[1])
    seen = 0
    for rel, call in py_calls("concatenate"):
        if not (call.args and isinstance(call.args[0], (ast.List, ast.Tuple))):
            continue
        parts = []
        for el in call.args[0].elts:
            names = [n.attr for n in ast.walk(el) if isinstance(n, ast.Attribute) and n.attr in dict(want)]
            widths = [n.args[-1].value for n in ast.walk(el) if isinstance(n, ast.Call) and isinstance(
                n.func, ast.Attribute) and n.func.attr == "reshape" and isinstance(n.args[-1], ast.Constant)]
            parts.append((names[0] if names else None, widths[0] if widths else None))
        if not any(n for n, _ in parts):
            continue
        seen += 1
        got, pos = [], 0
        for name, w in parts:
            got.append((name, (pos, pos + (w or 0))))
            pos += w or 0
        assert got == want, f"{rel}:{call.lineno} packs the record as {got}, rasterize.cl order gives {want}"
    assert seen, "no concatenate([... .v_means2d ...]) packing found in reings/ (renamed? update this test)"


# }}}

# {{{ other shared records


def test_grad_mask_bits_match():
    """project_bwd's `grad_mask` bits (comment and the bits the kernel tests) vs Python's GRAD_BITS."""
    text = c_text("project.cl")
    m = re.search(r"grad_mask bits:\s*([^\n*]*)", text)
    assert m, "project.cl: no `grad_mask bits: 1 means, ...` comment"
    bits = {name: int(b) for b, name in re.findall(r"(\d+)\s+(\w+)", m.group(1))}
    used = {int(b) for b in re.findall(r"grad_mask\s*&\s*(\d+)", _strip_comments(text))}
    assert used == set(bits.values()), f"project.cl tests grad_mask bits {sorted(used)}, comment lists {bits}"
    for mod, val in py_definitions("GRAD_BITS"):
        assert dict(val) == bits, f"{mod}.GRAD_BITS = {val}, project.cl says {bits}"


def test_packed_record_size():
    """raster_prep_one (common.h; called by rasterize_prep and project_fwd) writes a [N, 16] float record that
    rasterize.cl reads as float16 vectors; Python sizes it PACKED_BYTES."""
    text = _strip_comments(c_text("rasterize.cl"))
    m = re.search(r"__global float \*packed\s*,", text)
    assert m, "rasterize.cl: rasterize_prep's `__global float *packed` not found"
    stride = re.findall(r"packed \+ \(size_t\)g \* (\d+)", _strip_comments(c_text("common.h")))
    assert stride, "common.h: no `packed + (size_t)g * K` store in raster_prep_one"
    readers = re.findall(r"__global const (float\d*) \*packed", text)
    assert readers and set(readers) == {f"float{stride[0]}"}, f"packed is written {stride[0]} floats wide, read as {readers}"
    comment = re.search(r"\*packed,\s*// \[N, (\d+)\]", c_text("rasterize.cl"))
    assert comment and comment.group(1) == stride[0], "rasterize_prep's shape comment disagrees with its stride"
    for mod, val in py_definitions("PACKED_BYTES"):
        assert val == 4 * int(stride[0]), f"{mod}.PACKED_BYTES = {val}, rasterize.cl record is {stride[0]} floats"


# depth_loss.cl scratch buffers: kernel parameter -> Python scratch name (sizes in elements)
DEPTH_LOSS_BUFFERS = {"bstats": "dl_bstats", "sstats": "dl_sstats", "pcnt": "dl_pcnt", "prec": "dl_prec"}


def test_depth_loss_scratch_sizes():
    """The host allocates each depth-loss scratch buffer with the element count of its C shape
    comment (`// [2, Bcap, REC]` ...), evaluated at Bcap = 1 and at Bcap = 7."""
    text = c_text("depth_loss.cl")
    shapes = {}
    for param, dims in re.findall(r"\*(\w+),?\s*//\s*\[([^\]]+)\]", text):
        if param in DEPTH_LOSS_BUFFERS:
            shapes.setdefault(param, set()).add(dims.replace(" ", ""))
    assert set(shapes) == set(DEPTH_LOSS_BUFFERS), f"depth_loss.cl shape comments found for {sorted(shapes)}"
    for param, scratch in DEPTH_LOSS_BUFFERS.items():
        assert len(shapes[param]) == 1, f"depth_loss.cl {param} has several shapes {shapes[param]}"
        dims = shapes[param].pop().split(",")
        allocs = []
        for rel, call in py_calls("get"):
            args = call.args
            for i, a in enumerate(args[:-1]):
                if isinstance(a, ast.Constant) and a.value == scratch:
                    allocs.append((rel, call.lineno, args[i + 1]))
        assert allocs, f"no scratch allocation named {scratch!r} in reings/"
        for bcap in (1, 7):
            want = 1
            for d in dims:
                want *= c_eval(d.replace("Bcap", str(bcap)), "depth_loss.cl")
            for rel, line, expr in allocs:
                got = eval(compile(ast.Expression(expr), str(rel), "eval"), {"__builtins__": {}, "bcap": bcap})
                assert got == want, (f"{rel}:{line} allocates {scratch} with {ast.unparse(expr)} = {got} elements at "
                                     f"bcap={bcap}; depth_loss.cl says [{', '.join(dims)}] = {want}")


# }}}
