"""Read and write the standard 3DGS .ply (what graphdeco's `save_ply` writes and viewers read),
without plyfile: the header and the numpy record dtype are written here.

Layout: binary little-endian, one `vertex` element, float32 properties in this order:
    x y z  nx ny nz (zeros)  f_dc_0..2  f_rest_0..3(K-1)-1  opacity  scale_0..2  rot_0..3
f_rest is channel-major as 3DGS stores it (`features_rest.transpose(1, 2).flatten(1)`):
    f_rest_{c*(K-1) + k} = sh[:, 1 + k, c].
opacity is the logit, scale_* the log-scales, rot_* the quaternion (w, x, y, z), unnormalised.
The reader accepts any property order, extra properties, float64/other scalar types, big-endian,
and further elements after the vertices; it raises `PlyError` naming what is wrong otherwise.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..types import SH_COUNTS, Gaussians


class PlyError(ValueError):
    """A .ply file that is not a readable 3DGS point cloud (the message says why)."""


_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def attribute_names(sh_degree: int) -> list[str]:
    """Vertex property names of a 3DGS ply for an SH degree (3DGS `construct_list_of_attributes`)."""
    k = SH_COUNTS[sh_degree]
    return (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
            + [f"f_rest_{i}" for i in range(3 * (k - 1))] + ["opacity"]
            + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


def write_ply(path, g: Gaussians, comments=()) -> None:
    """Write `g` as a binary little-endian 3DGS .ply; `comments`: header comment lines (one line
    each, ASCII, e.g. provenance)."""
    comments = [str(c) for c in comments]
    for c in comments:
        if "\n" in c or "\r" in c or not c.isascii():
            raise ValueError(f"write_ply: a header comment must be one ASCII line, got {c!r}")
    names = attribute_names(g.sh_degree)
    n, k = len(g), g.sh.shape[1]
    rec = np.zeros(n, dtype=np.dtype([(a, "<f4") for a in names]))
    for i, a in enumerate("xyz"):
        rec[a] = g.means[:, i]
    for c in range(3):
        rec[f"f_dc_{c}"] = g.sh[:, 0, c]
        for j in range(k - 1):
            rec[f"f_rest_{c * (k - 1) + j}"] = g.sh[:, 1 + j, c]
    rec["opacity"] = g.opacity_logits
    for i in range(3):
        rec[f"scale_{i}"] = g.log_scales[:, i]
    for i in range(4):
        rec[f"rot_{i}"] = g.quats[:, i]
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments), f"element vertex {n}"]
    header += [f"property float {a}" for a in names] + ["end_header"]
    from .files import atomic_write

    with atomic_write(path, binary=True) as f:  # whole or not at all; never through a planted symlink
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())


def _parse_header(f, path):
    first = f.readline()
    if first.strip() != b"ply":
        raise PlyError(f"{path}: not a PLY file (first line {first[:20]!r}, expected 'ply')")
    fmt, elements = None, []  # elements: [name, count, [(prop, type) | ("list", ...)]]
    while True:
        line = f.readline()
        if not line:
            raise PlyError(f"{path}: header ends without 'end_header'")
        try:
            words = line.decode("ascii").split()
        except UnicodeDecodeError as e:
            raise PlyError(f"{path}: non-ASCII header line {line[:40]!r}") from e
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            if len(words) < 2:
                raise PlyError(f"{path}: malformed format line {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{path}: malformed element line {line!r}")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise PlyError(f"{path}: property before any element: {line!r}")
            if len(words) == 5 and words[1] == "list":
                elements[-1][2].append(("list", words[2], words[3], words[4]))
            elif len(words) == 3 and words[1] in _TYPES:
                if any(prop[0] == words[2] for prop in elements[-1][2]):
                    raise PlyError(f"{path}: property {words[2]!r} appears twice in element {elements[-1][0]!r}")
                elements[-1][2].append((words[2], _TYPES[words[1]]))
            else:
                raise PlyError(f"{path}: unsupported property line {line!r}")
        else:
            raise PlyError(f"{path}: unknown header keyword {words[0]!r}")
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise PlyError(f"{path}: format {fmt!r} is not supported (binary_little_endian or binary_big_endian)")
    return fmt, elements


def pad_sh(g: Gaussians, sh_degree: int) -> Gaussians:
    """`g` with its SH coefficients zero-padded (or cut) to `sh_degree`: the same colours up to
    that degree (the extra bands are zero), for viewers that expect a fixed degree (3)."""
    if sh_degree not in range(len(SH_COUNTS)):
        raise ValueError(f"sh_degree must be 0..{len(SH_COUNTS) - 1}, got {sh_degree!r}")
    k = SH_COUNTS[sh_degree]
    sh = np.zeros((len(g), k, 3), np.float32)
    m = min(k, g.sh.shape[1])
    sh[:, :m] = g.sh[:, :m]
    return Gaussians(g.means, g.quats, g.log_scales, g.opacity_logits, sh)


def read_ply(path) -> Gaussians:
    """Read a 3DGS .ply into `Gaussians` (SH degree from the number of f_rest_* properties)."""
    path = Path(path)
    with open(path, "rb") as f:
        fmt, elements = _parse_header(f, path)
        endian = "<" if fmt == "binary_little_endian" else ">"
        left = os.fstat(f.fileno()).st_size - f.tell()  # bytes after the header
        for name, count, props in elements:
            if any(p[0] == "list" for p in props):
                raise PlyError(f"{path}: element {name!r} has list properties; it must come after 'vertex'")
            if name == "vertex" and not props:
                raise PlyError(f"{path}: the 'vertex' element has no properties (missing vertex properties)")
            dt = np.dtype([(p[0], endian + p[1]) for p in props])
            need = dt.itemsize * count
            if need > left:  # checked before reading: a header's count cannot make us allocate more than the file
                raise PlyError(f"{path}: truncated or corrupt: the header's {count} {name} elements need {need} bytes, "
                               f"the file has {left} after the header")
            left -= need
            if name != "vertex":
                f.seek(need, 1)
                continue
            buf = f.read(need)
            if len(buf) != dt.itemsize * count:
                raise PlyError(f"{path}: truncated: {count} vertices need {dt.itemsize * count} bytes, got {len(buf)}")
            rec = np.frombuffer(buf, dtype=dt)
            break
        else:
            raise PlyError(f"{path}: no 'vertex' element")
    have = set(rec.dtype.names or ())
    n_rest = sum(1 for a in have if a.startswith("f_rest_"))
    if n_rest % 3 or (n_rest // 3 + 1) not in SH_COUNTS:
        raise PlyError(f"{path}: {n_rest} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0-3)")
    k = n_rest // 3 + 1
    need = [a for a in attribute_names(SH_COUNTS.index(k)) if a not in ("nx", "ny", "nz")]
    missing = [a for a in need if a not in have]
    if missing:
        raise PlyError(f"{path}: missing vertex properties {missing}")
    col = lambda a: rec[a].astype(np.float32)
    sh = np.zeros((len(rec), k, 3), np.float32)
    for c in range(3):
        sh[:, 0, c] = col(f"f_dc_{c}")
        for j in range(k - 1):
            sh[:, 1 + j, c] = col(f"f_rest_{c * (k - 1) + j}")
    return Gaussians(np.stack([col(a) for a in "xyz"], 1), np.stack([col(f"rot_{i}") for i in range(4)], 1),
                     np.stack([col(f"scale_{i}") for i in range(3)], 1), col("opacity"), sh)
