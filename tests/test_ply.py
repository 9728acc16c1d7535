"""3DGS .ply: round trip at every SH degree, the exact 3DGS layout (names, order, channel-major
f_rest), tolerant reading, and clear errors on malformed files."""
from __future__ import annotations

import numpy as np
import pytest

from reings.io import PlyError, read_ply, write_ply
from reings.io.ply import attribute_names
from reings.types import Gaussians


def _g(rng, n, deg):
    k = (1, 4, 9, 16)[deg]
    return Gaussians(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)),
                     rng.normal(size=n), rng.normal(size=(n, k, 3)))


@pytest.mark.parametrize("deg", [0, 1, 2, 3])
@pytest.mark.parametrize("n", [0, 1, 37])
def test_roundtrip(tmp_path, rng, deg, n):
    g = _g(rng, n, deg)
    write_ply(tmp_path / "a.ply", g)
    h = read_ply(tmp_path / "a.ply")
    for a, b in zip(g.astuple(), h.astuple()):
        np.testing.assert_array_equal(a, b)


def test_layout_matches_3dgs(tmp_path, rng):
    g = _g(rng, 5, 3)
    p = tmp_path / "a.ply"
    write_ply(p, g)
    raw = p.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    names = [l.split()[2] for l in lines[3:]]
    assert names == attribute_names(3) and len(names) == 62  # 3DGS SH3: 62 floats
    assert all(l.split()[1] == "float" for l in lines[3:])
    rec = np.frombuffer(body, dtype=np.dtype([(a, "<f4") for a in names]))
    # 3DGS: features_rest [N,15,3] -> transpose(1,2) -> [N,3,15] -> flatten: channel-major
    want = g.sh[:, 1:, :].transpose(0, 2, 1).reshape(5, -1)
    np.testing.assert_array_equal(np.stack([rec[f"f_rest_{i}"] for i in range(45)], 1), want)
    np.testing.assert_array_equal(rec["rot_0"], g.quats[:, 0])  # w first
    np.testing.assert_array_equal(rec["opacity"], g.opacity_logits)
    assert np.all(rec["nx"] == 0)


def _write_custom(path, props, rec_bytes, n, fmt="binary_little_endian", extra=""):
    head = ["ply", f"format {fmt} 1.0", "comment made by a test", f"element vertex {n}"]
    head += [f"property {t} {a}" for t, a in props] + ([extra] if extra else []) + ["end_header"]
    path.write_bytes(("\n".join(head) + "\n").encode() + rec_bytes)


def test_reads_other_orders_types_and_endianness(tmp_path, rng):
    g = _g(rng, 4, 0)
    names = [a for a in attribute_names(0) if a[0] != "n"][::-1] + ["red"]
    types = {a: ("double" if a.startswith("scale") else "float") for a in names}
    types["red"] = "uchar"
    for fmt, e in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
        dt = np.dtype([(a, e + {"double": "f8", "float": "f4", "uchar": "u1"}[types[a]]) for a in names])
        rec = np.zeros(4, dt)
        for i, a in enumerate("xyz"):
            rec[a] = g.means[:, i]
        for c in range(3):
            rec[f"f_dc_{c}"] = g.sh[:, 0, c]
        rec["opacity"] = g.opacity_logits
        for i in range(3):
            rec[f"scale_{i}"] = g.log_scales[:, i]
        for i in range(4):
            rec[f"rot_{i}"] = g.quats[:, i]
        p = tmp_path / f"{fmt}.ply"
        _write_custom(p, [(types[a], a) for a in names], rec.tobytes() + b"\x00" * 9, 4, fmt,
                      extra="element face 1\nproperty list uchar int vertex_indices")
        h = read_ply(p)
        for a, b in zip(g.astuple(), h.astuple()):
            np.testing.assert_array_equal(a, b)


def test_malformed(tmp_path, rng):
    p = tmp_path / "bad.ply"
    p.write_bytes(b"hello\n")
    with pytest.raises(PlyError, match="not a PLY"):
        read_ply(p)
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(PlyError, match="ascii"):
        read_ply(p)
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n")
    with pytest.raises(PlyError, match="end_header"):
        read_ply(p)
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n\0\0\0\0")
    with pytest.raises(PlyError, match="missing vertex properties"):
        read_ply(p)
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty float x\nend_header\n\0\0\0\0")
    with pytest.raises(PlyError, match="no 'vertex'"):
        read_ply(p)
    g = _g(rng, 3, 1)
    write_ply(p, g)
    raw = p.read_bytes()
    p.write_bytes(raw[:-5])
    with pytest.raises(PlyError, match="truncated"):
        read_ply(p)
    p.write_bytes(raw.replace(b"property float f_rest_8\n", b""))
    with pytest.raises(PlyError, match="f_rest"):
        read_ply(p)
    p.write_bytes(raw.replace(b"property float x\n", b"property quux x\n"))
    with pytest.raises(PlyError, match="unsupported property"):
        read_ply(p)


def test_absurd_vertex_count_is_a_named_error(tmp_path, rng):
    """Issue 14 item 14: a header claiming 10^15 vertices raised MemoryError (the read was sized
    from the header); the count is now checked against the file's size first."""
    p = tmp_path / "huge.ply"
    g = _g(rng, 3, 1)
    write_ply(p, g)
    raw = p.read_bytes()
    p.write_bytes(raw.replace(b"element vertex 3\n", b"element vertex 1000000000000000\n"))
    with pytest.raises(PlyError, match="1000000000000000 vertex elements need"):
        read_ply(p)
    p.write_bytes(raw.replace(b"element vertex 3\n", b"element face 99999999999\nproperty float q\nelement vertex 3\n"))
    with pytest.raises(PlyError, match="face elements need"):
        read_ply(p)
