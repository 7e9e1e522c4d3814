"""The PLY reader: ASCII and binary files read face for face; header counts, line shapes,
index ranges and the data's length checked, every fault refused with where it is."""
from __future__ import annotations

import struct

import numpy as np
import pytest
import trimesh
from helpers.refusals import assert_refused, write_file

import torchakvf as ta
from torchakvf import shapes
from torchakvf.io.ply import face_count, parse_header

_HEAD = ("ply\nformat ascii 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\n"
         "property float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n")
_TRI = "0 0 0\n1 0 0\n0 1 0\n"
_RNG_BYTES = np.random.default_rng(0).bytes(600)


def _ascii(nv, nf, body):
    return _HEAD.format(nv=nv, nf=nf) + body


@pytest.fixture(scope="module")
def sphere():
    s = shapes.icosphere(2)
    perm = np.random.default_rng(3).permutation(len(s.faces))
    return s.vertices, s.faces[perm]


def _binary_ply(vertices, faces, order="<", count_type="B", extra_face_list=False):
    kind = "little" if order == "<" else "big"
    head = (f"ply\nformat binary_{kind}_endian 1.0\ncomment made by a test\nelement vertex {len(vertices)}\n"
            "property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
            f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
            + ("property list uchar float texcoord\n" if extra_face_list else "") + "end_header\n")
    body = b"".join(struct.pack(order + "dddB", *v, 7) for v in vertices)
    for f in faces:
        body += struct.pack(order + count_type + "iii", 3, *f)
        if extra_face_list:
            body += struct.pack(order + "B6f", 6, *range(6))
    return head.encode() + body


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("extra_face_list", [False, True])
def test_binary_ply_read_face_for_face(tmp_path, sphere, order, extra_face_list):
    V, F = sphere
    path = write_file(tmp_path / "m.ply", _binary_ply(V, F, order, extra_face_list=extra_face_list))
    m = ta.load_mesh(path)
    np.testing.assert_array_equal(m.faces, F)
    np.testing.assert_array_equal(m.vertices, V)
    assert face_count(path.read_bytes(), "m") == len(F) == ta.io.peek_face_count(path)


def test_ascii_ply_with_extra_properties_and_elements(tmp_path):
    text = ("ply\r\nformat ascii 1.0\r\ncomment c\r\nelement vertex 4\r\nproperty float x\r\n"
            "property float y\r\nproperty float z\r\nproperty uchar red\r\nelement face 2\r\n"
            "property list uchar int vertex_index\r\nproperty int flags\r\nelement edge 1\r\n"
            "property int vertex1\r\nproperty int vertex2\r\nend_header\r\n"
            "0 0 0 1\r\n1 0 0 2\r\n0 1 0 3\r\n1 1 0 4\r\n3 0 1 2 9\r\n3 1 3 2 9\r\n0 1\r\n")
    m = ta.load_mesh(write_file(tmp_path / "x.ply", text))
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [1, 3, 2]])
    np.testing.assert_array_equal(m.vertices[3], [1, 1, 0])


def test_trimesh_written_ply_round_trips(tmp_path, sphere):
    V, F = sphere
    for kw in ({}, {"encoding": "ascii"}):
        path = tmp_path / "t.ply"
        trimesh.Trimesh(V, F, process=False).export(path, **kw)
        np.testing.assert_array_equal(ta.load_mesh(path).faces, F)


def test_shifted_and_truncated_ascii_ply_refused(tmp_path, sphere):
    """Face lines cut, shifted or duplicated: refused, never read as fewer or more faces."""
    V, F = sphere
    lines = [" ".join(repr(float(c)) for c in v) for v in V] + [f"3 {a} {b} {c}" for a, b, c in F]
    head = _HEAD.format(nv=len(V), nf=len(F))
    cases = {
        "cut": (lines[:-18], r"truncated: header declares 482 data lines \(162 vertex, 320 face\), file has 464"),
        "duplicated": (lines + lines[-1:], r"1 data line past the 482 the header declares \(first: line 492\)"),
        "deleted vertex": (lines[:5] + lines[6:], r"line 15 \(vertex 5\) holds 4 numbers|truncated"),
        "merged lines": (lines[:-2] + [lines[-2] + " " + lines[-1]], r"truncated|holds"),
    }
    for name, (body, problem) in cases.items():
        assert_refused(write_file(tmp_path / f"{name}.ply", head + "\n".join(body) + "\n"), problem)


BAD_FILES = {
    "out_of_range_ply": ("oor.ply", _ascii(3, 1, _TRI + "3 0 1 5\n"),
                         r"face 0 \(line 13\) has vertex index 5 outside 0\.\.2"),
    "negative_index": ("neg.ply", _ascii(3, 1, _TRI + "3 0 -1 2\n"), r"index -1 outside 0\.\.2"),
    "quad": ("quad.ply", _ascii(4, 1, _TRI + "1 1 0\n4 0 1 2 3\n"),
             r"face 0 \(line 14\) has 4 vertices; only triangle"),
    "short_face": ("short.ply", _ascii(3, 1, _TRI + "3 0 1\n"), r"line 13 \(face 0\) ends before"),
    "long_face": ("long.ply", _ascii(3, 1, _TRI + "3 0 1 2 2\n"), r"line 13 \(face 0\) holds 5 numbers"),
    "word": ("word.ply", _ascii(3, 1, "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n"),
             r"line 11 \(vertex 1\): 'zero' is not a number"),
    "float_index": ("fi.ply", _ascii(3, 1, _TRI + "3 0 1 2.5\n"), r"'2.5' \(vertex_indices\) is not an integer"),
    "nan": ("nan.ply", _ascii(3, 1, "0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n"), r"NaN or infinite"),
    "garbage_ply": ("garbage.ply", _RNG_BYTES, r"missing the 'ply' header"),
    "no_end_header": ("ne.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", r"no 'end_header'"),
    "no_format": ("nf.ply", "ply\nelement vertex 3\nend_header\n", r"no 'format' line"),
    "bad_header_line": ("bh.ply", "ply\nformat ascii 1.0\nelement vertex three\nend_header\n",
                        r"header line 3 'element vertex three': expected 'element <name> <count>'"),
    "unknown_type": ("ut.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty real x\nend_header\n",
                     r"header line 4 .*known type"),
    "no_faces": ("nof.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 "property float z\nend_header\n" + _TRI, r"must declare 'element vertex' and 'element face'"),
    "no_z": ("noz.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
             "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0\n", r"no 'z' property"),
    "empty": ("empty.ply", _ascii(3, 0, _TRI), r"empty mesh \(3 vertices, 0 faces\)"),
    "ply_truncated_body": ("short.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n"
                           b"property float x\nproperty float y\nproperty float z\nelement face 50\n"
                           b"property list uchar int vertex_indices\nend_header\n" + _RNG_BYTES[:200],
                           r"truncated: header declares 100 vertex elements, the file has room for 16"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_ply_files_are_refused(tmp_path, case):
    fname, content, problem = BAD_FILES[case]
    assert_refused(write_file(tmp_path / fname, content), problem)


def test_binary_ply_faults_refused_with_where(tmp_path, sphere):
    V, F = sphere
    good = _binary_ply(V, F)
    assert_refused(write_file(tmp_path / "cut.ply", good[:-7]),
                   r"truncated: header declares 320 face elements, the data ends inside face 319 \(at byte")
    assert_refused(write_file(tmp_path / "tail.ply", good + b"\0\0\0"),
                   r"3 bytes past the last element the header declares")
    quad = bytearray(good)
    face_start = len(good) - 13 * len(F)
    quad[face_start + 13 * 4] = 4                                   # face 4 claims 4 corners
    assert_refused(write_file(tmp_path / "quad.ply", bytes(quad)),
                   r"face 4 has 4 vertices; only triangle meshes are supported")
    wild = bytearray(good)
    wild[face_start + 13 * 9 + 1:face_start + 13 * 9 + 5] = struct.pack("<i", 99999)
    assert_refused(write_file(tmp_path / "wild.ply", bytes(wild)), r"face 9 has vertex index 99999 outside 0\.\.161")
    first = bytearray(good)
    first[face_start] = 2
    assert_refused(write_file(tmp_path / "first.ply", bytes(first)), r"face 0 has 2 vertices")


def test_header_is_read_with_its_counts():
    h = parse_header(_ascii(3, 1, _TRI + "3 0 1 2\n").encode(), "x")
    assert h.encoding == "ascii" and [(e.name, e.count) for e in h.elements] == [("vertex", 3), ("face", 1)]
    assert h.lines == 9 and h.elements[1].properties[0].is_list


def test_a_wild_list_length_is_truncation_not_a_huge_read(tmp_path):
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            b"property float z\nproperty list uint float foo\nelement face 1\n"
            b"property list uchar int vertex_indices\nend_header\n")
    body = struct.pack("<fffI", 0, 0, 0, 0xFFFFFFFF) + b"\0" * 40
    assert_refused(write_file(tmp_path / "w.ply", head + body),
                   r"truncated: header declares 1 vertex elements, the data ends inside vertex 0 "
                   r".*\(its list 'foo' says 4294967295 items\)")


def test_faces_with_lists_of_varying_length_are_walked(tmp_path, sphere):
    V, F = sphere
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(F)}\n"
            "property list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n")
    body = b"".join(struct.pack("<ddd", *v) for v in V)
    for i, f in enumerate(F):
        n = 6 if i % 2 == 0 else 0                                   # every other face has none
        body += struct.pack("<Biii", 3, *f) + struct.pack(f"<B{n}f", n, *range(n))
    np.testing.assert_array_equal(ta.load_mesh(write_file(tmp_path / "v.ply", head.encode() + body)).faces, F)
    bad = bytearray(head.encode() + body)
    at = len(head) + 24 * len(V) + (13 + 25) + (13 + 1)              # face 2: after a 6-item and a 0-item face
    bad[at] = 4
    assert_refused(write_file(tmp_path / "q.ply", bytes(bad)), r"face 2 has 4 vertices")
