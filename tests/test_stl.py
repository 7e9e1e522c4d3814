"""The STL reader: binary and ASCII files read facet for facet; a binary file whose size
disagrees with its count, and an ASCII file off its grammar, refused with where."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers.refusals import assert_refused, write_file

import torchakvf as ta
from torchakvf import shapes
from torchakvf.io.stl import is_binary

_FACET = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n"
_RNG_BYTES = np.random.default_rng(0).bytes(600)


@pytest.fixture(scope="module")
def sphere_stl():
    s = shapes.icosphere(1)
    mesh = trimesh.Trimesh(s.vertices, s.faces, process=False)
    return s, mesh.export(file_type="stl"), mesh.export(file_type="stl_ascii").encode()


def test_binary_and_ascii_read_facet_for_facet(tmp_path, sphere_stl):
    s, binary, text = sphere_stl
    for name, data in (("b.stl", binary), ("a.stl", text)):
        path = write_file(tmp_path / name, data)
        m = ta.load_mesh(path)
        assert m.n_faces == len(s.faces) == ta.io.peek_face_count(path)
        np.testing.assert_allclose(m.vertices[m.faces], s.vertices[s.faces], atol=1e-6)
    assert is_binary(binary) and not is_binary(text)


def test_binary_header_starting_with_solid_is_binary(tmp_path, sphere_stl):
    s, binary, _ = sphere_stl
    data = b"solid looks like text".ljust(80, b" ") + binary[80:]
    assert ta.load_mesh(write_file(tmp_path / "s.stl", data)).n_faces == len(s.faces)


def test_two_solids_and_bare_facets():
    from torchakvf.io.stl import parse_stl
    text = "solid a\n" + _FACET + "endsolid a\nsolid b\n" + _FACET.replace("facet normal 0 0 1", "facet") + "endsolid\n"
    v, f = parse_stl(text.encode(), "two")
    assert f.shape == (2, 3) and v.shape == (6, 3)


def _ascii(body):
    return "solid t\n" + body + "endsolid t\n"


BAD_FILES = {
    "truncated_binary": ("tb.stl", None, r"truncated: header says 80 triangles, file has room for 79"),
    "binary_tail": ("bt.stl", None, r"7 bytes past the 80 triangles the header says"),
    "short_binary": ("sb.stl", b"\x01\x02" * 20,
                     r"truncated: a binary STL starts with an 84-byte header, the file has 40 bytes"),
    "garbage_stl": ("garbage.stl", _RNG_BYTES, r"truncated: header says \d+ triangles, file has room for 10"),
    "quad_facet": ("q.stl", _ascii(_FACET.replace("endloop", "  vertex 1 1 0\n endloop")),
                   r"facet 0 \(line 2\) has 4 vertices; only triangles"),
    "two_vertices": ("t.stl", _ascii(_FACET.replace("  vertex 0 1 0\n", "")), r"facet 0 \(line 2\) has 2 vertices"),
    "cut_ascii": ("c.stl", _ascii(_FACET)[:-40], r"truncated: the file ends inside line 6 \(facet 0\)"),
    "cut_at_line_end": ("ce.stl", _ascii(_FACET)[:-45], r"truncated: the file ends inside facet 0 \(line 2\)"),
    "no_endsolid": ("n.stl", "solid t\n" + _FACET, r"truncated: the file ends inside a solid, after 1 facets"),
    "word": ("w.stl", _ascii(_FACET.replace("vertex 1 0 0", "vertex 1 x 0")), r"facet 0: 'x' is not a number"),
    "stray_line": ("s.stl", _ascii(_FACET.replace(" endloop", " color 1\n endloop")),
                   r"line 7: 'color 1' where the STL grammar expects 'endloop' or 'vertex' \(facet 0\)"),
    "short_vertex": ("sv.stl", _ascii(_FACET.replace("vertex 1 0 0", "vertex 1 0")),
                     r"line 5: vertex of facet 0 does not hold 3"),
    "no_facets": ("e.stl", "solid t\nendsolid t\n", r"no triangles found"),
    "zero_binary": ("z.stl", b"\0" * 84, r"empty mesh"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_stl_files_are_refused(tmp_path, case, sphere_stl):
    fname, content, problem = BAD_FILES[case]
    _, binary, _ = sphere_stl
    if case == "truncated_binary":
        content = binary[:-30]
    elif case == "binary_tail":
        content = binary + b"\0" * 7
    assert_refused(write_file(tmp_path / fname, content), problem)


def test_truncated_binary_header_count_is_refused_by_peek_too(tmp_path, sphere_stl):
    _, binary, _ = sphere_stl
    path = write_file(tmp_path / "tb.stl", binary[:-30])
    with pytest.raises(ta.MeshError, match="header says 80 triangles, file has room for 79"):
        ta.io.peek_face_count(path)


def test_the_plain_ascii_reader_equals_the_line_reader(sphere_stl):
    from torchakvf.io.stl import read_ascii_lines, read_plain_ascii
    _, _, text = sphere_stl
    text = text.decode()
    plain = read_plain_ascii(text)
    assert plain is not None and plain.tobytes() == read_ascii_lines(text, "x").tobytes()
    for other in (text.replace("vertex", "VERTEX", 1),                # keywords in capitals
                  text.replace("endsolid", "endsolid a\nsolid b\n" + _FACET + "endsolid"),   # two solids
                  text.replace("facet normal", "facet\nnormal", 1)):  # a line split
        assert read_plain_ascii(other) is None
    assert len(read_ascii_lines(text.replace("vertex", "VERTEX", 1), "x")) == 80
