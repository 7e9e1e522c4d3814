"""The OBJ reader: one triangle per 'f' line in file order, every corner form and negative
indices; polygons, bad corners and indices outside the file refused with the line."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.refusals import assert_refused, write_file

import torchakvf as ta
from torchakvf.io.obj import face_count, parse_obj

_SQUARE = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
_RNG_BYTES = np.random.default_rng(0).bytes(600)


def test_corner_forms_and_negative_indices():
    text = ("# a square in two triangles\nmtllib m.mtl\no square\n" + _SQUARE +
            "vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\ng half\nusemtl red\ns off\n"
            "f 1/1/1 2/2/1 3/3/1\n"
            "f -4//1 \\\n -2//1 -1//1\n"                       # negative, continued line
            "l 1 2\np 3\n")
    v, f = parse_obj(text.encode(), "sq.obj")
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(v[2], [1, 1, 0])
    assert face_count(text.encode()) == 2


def test_negative_indices_count_back_from_their_line():
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nf -4 -3 -1\n"
    np.testing.assert_array_equal(parse_obj(text.encode(), "n")[1], [[0, 1, 2], [0, 1, 3]])


BAD_FILES = {
    "obj_quad": ("quad.obj", _SQUARE + "f 1 2 3 4\n", r"face 0 \(line 5\) has 4 corners; only triangle"),
    "two_corners": ("two.obj", _SQUARE + "f 1 2 3\nf 1 2\n", r"face 1 \(line 6\) has fewer than 3 corners"),
    "huge_index": ("huge.obj", _SQUARE + "f 1 2 99999999998\n",
                   r"face 0 \(line 5\): vertex index 99999999998 outside 1\.\.4"),
    "zero_index": ("zero.obj", _SQUARE + "f 0 1 2\n", r"vertex index 0 outside 1\.\.4"),
    "negative_too_far": ("neg.obj", _SQUARE + "f -5 1 2\n", r"vertex index -5 outside -4\.\.-1 here"),
    "texture_index": ("vt.obj", _SQUARE + "vt 0 0\nf 1/2 2/1 3/1\n", r"texture coordinate index 2 outside 1\.\.1"),
    "normal_missing": ("vn.obj", _SQUARE + "f 1//1 2//1 3//1\n", r"normal index 1 outside none"),
    "bad_corner": ("corner.obj", _SQUARE + "f 1 2 x\n", r"corner 'x' is not 'v', 'v/vt'"),
    "float_corner": ("fc.obj", _SQUARE + "f 1 2 3.0\n", r"corner '3.0' is not"),
    "short_vertex": ("sv.obj", "v 0 0\n" + _SQUARE + "f 1 2 3\n", r"line 1: vertex 'v 0 0' does not hold 3"),
    "word_vertex": ("wv.obj", "v 0 zero 0\n" + _SQUARE + "f 1 2 3\n", r"vertex 1: 'zero' is not a number"),
    "nan_obj": ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", r"NaN or infinite"),
    "no_faces": ("nof.obj", _SQUARE, r"no triangles found .*no 'f' lines"),
    "no_vertices": ("nov.obj", "f 1 2 3\n", r"no vertices in this OBJ file"),
    "not_a_statement": ("ns.obj", _SQUARE + "1 2 3\nf 1 2 3\n", r"line 5: '1' is not an OBJ statement"),
    "garbage_obj": ("garbage.obj", _RNG_BYTES, r"not a text OBJ file"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_obj_files_are_refused(tmp_path, case):
    fname, content, problem = BAD_FILES[case]
    assert_refused(write_file(tmp_path / fname, content), problem)


def test_face_lines_cut_or_doubled_change_the_declared_count_alike(tmp_path):
    from torchakvf import shapes
    s = shapes.icosphere(1)
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in s.vertices.tolist()]
    faces = [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in s.faces.tolist()]
    for body in (lines + faces[:-3], lines + faces + faces[-1:]):
        path = write_file(tmp_path / "m.obj", "\n".join(body) + "\n")
        assert ta.load_mesh(path).n_faces == len(body) - len(lines) == ta.io.peek_face_count(path)
