"""The OFF reader: the vectorized readers equal the line reader bit for bit, and every
malformed file is refused with the line reader's words."""
from __future__ import annotations

import gzip

import numpy as np
import pytest
from helpers.refusals import assert_refused, write_file

import torchakvf as ta
from torchakvf import shapes

_TRI = "0 0 0\n1 0 0\n0 1 0\n"
_RNG_BYTES = np.random.default_rng(0).bytes(600)

BAD_FILES = {
    # name: (file name, content, problem regex)
    "zero_faces": ("nofaces.off", "OFF\n3 0 0\n" + _TRI, r"empty mesh .*0 faces"),
    "nan": ("nan.off", "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", r"NaN or infinite"),
    "inf": ("inf.off", "OFF\n3 1 0\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n", r"NaN or infinite"),
    "out_of_range": ("oor.off", "OFF\n3 1 0\n" + _TRI + "3 0 1 3\n", r"index 3 outside 0\.\.2"),
    "negative": ("neg.off", "OFF\n3 1 0\n" + _TRI + "3 0 -1 2\n", r"index -1 outside 0\.\.2"),
    "off_quad": ("quad.off", "OFF\n4 1 0\n" + _TRI + "1 1 0\n4 0 1 3 2\n", r"4 vertices.*triangle"),
    "garbage_off": ("garbage.off", _RNG_BYTES, r"garbage|binary|header"),
    "truncated_off": ("trunc.off", "OFF\n3 2 0\n" + _TRI + "3 0 1 2\n", r"truncated"),
    "bad_vertex_line": ("badv.off", "OFF\n3 1 0\n0 0 0\n1 x 0\n0 1 0\n3 0 1 2\n", r"vertex line"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_off_files_are_refused(tmp_path, case):
    fname, content, problem = BAD_FILES[case]
    assert_refused(write_file(tmp_path / fname, content), problem)


def test_psb_read_off_is_load_mesh(tmp_path):
    from torchakvf.evaluate.psb import read_off

    s = shapes.dumbbell(n_around=10)
    text = "OFF\n# a comment\n" + f"{len(s.vertices)} {len(s.faces)} 0\n"
    text += "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in s.vertices.tolist())
    text += "".join(f"3 {a} {b} {c}\n" for a, b, c in s.faces.tolist())
    (tmp_path / "m.off.gz").write_bytes(gzip.compress(text.encode()))
    v, f = read_off(tmp_path / "m.off.gz")
    mesh = ta.load_mesh(tmp_path / "m.off.gz")
    np.testing.assert_array_equal(v, mesh.vertices)
    np.testing.assert_array_equal(f, mesh.faces)
    np.testing.assert_array_equal(v, s.vertices)
    assert ta.io.peek_face_count(tmp_path / "m.off.gz") == len(s.faces)
    (tmp_path / "q.off").write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n4 0 1 2 3\n")
    for reader in (read_off, ta.load_mesh):   # the same strict parser: no silent split
        with pytest.raises(ta.errors.MeshError, match="face 0 has 4 vertices"):
            reader(tmp_path / "q.off")



@pytest.mark.parametrize("text", [
    "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "off\r\n3 1 0\r\n\r\n0.5e1 -0 .25\r\n1 0 0 255 0 0\r\n0 1 0\r\n\t3 0 1 2 7 7 7\r\n",   # extras, CRLF
    "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 2 1 0\n",   # a line past the counts
])
def test_vectorized_off_reader_equals_the_line_reader(text):
    from torchakvf.io.off import parse_off, parse_off_by_lines, parse_plain_off
    raw = text.encode()
    fast = parse_plain_off(raw)
    assert fast is not None                                   # taken by the fast reader
    ref = parse_off_by_lines(raw, "x.off")
    for a, b in zip(fast, ref):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert all(np.array_equal(a, b) for a, b in zip(parse_off(raw, "x.off"), ref))


@pytest.mark.parametrize("body, by_text_reader", [
    ("0.1 -2.5e-3 7\n1e-320 .5 -0\n3.14159265358979323846264 1E+2 +4\n3 0 1 2\n", True),
    ("0.1 -2.5e-3 7\n\n1 0 0\n0 1 0\n\n3 +0 1 2\n", True),          # blank lines, a signed index
    ("1 0 0\n0 1 0\n0 0 1\n3 0 1 2", True),                             # no newline at the end
    ("nan 0 0\n1 0 0\n0 1 inf\n3 0 1 2\n", False),                    # read as Python's float does
    ("1_0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", False),
    ("1 0 0\n1 0 0\n0 1 0\n3 0 1_0 2\n", False),
])
def test_off_text_reader_equals_the_line_reader_bitwise(body, by_text_reader, monkeypatch):
    """The usual file goes to numpy's text reader (:func:`read_sections`), whose numbers are
    Python's float/int bit for bit (correctly rounded, subnormals too); bytes it is not given
    (nan, underscores) go the token way, with the same values as the line reader."""
    from torchakvf.io import off
    raw = ("OFF\n3 1 0\n" + body).encode()
    taken, real = [], off.read_sections
    monkeypatch.setattr(off, "read_sections", lambda *a: taken.append(real(*a)) or taken[-1])
    fast = off.parse_off(raw, "x.off")
    assert (len(taken) == 1 and taken[0] is not None) == by_text_reader
    ref = off.parse_off_by_lines(raw, "x.off")
    for a, b in zip(fast, ref):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_off_text_reader_on_random_digits_equals_python_float():
    from torchakvf.io.off import parse_off
    rng = np.random.default_rng(5)
    x = rng.normal(size=(200, 3)) * 10.0 ** rng.integers(-30, 30, size=(200, 3))
    text = "".join(" ".join(repr(float(t)) if i % 3 else f"{t:.25g}" for i, t in enumerate(row)) + "\n"
                   for row in x)
    raw = f"OFF\n200 1 0\n{text}3 0 1 2\n".encode()
    expect = np.array([[float(t) for t in line.split()] for line in text.splitlines()])
    assert parse_off(raw, "x.off")[0].tobytes() == expect.tobytes()


@pytest.mark.parametrize("text, problem", [
    ("OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", "vertex line"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2 0\n", "only triangle"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", "fewer than 3"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2.5\n", "non-integer"),
    ("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "truncated"),
    ("# c\nOFF\n3 1 0\n0 0 0\n1 0 0\n0 x 0\n3 0 1 2\n", "3 numbers"),
])
def test_off_files_the_fast_reader_declines_get_the_line_readers_error(text, problem):
    from torchakvf.io.off import parse_off, parse_plain_off
    assert parse_plain_off(text.encode()) is None
    with pytest.raises(ta.MeshError, match=problem):
        parse_off(text.encode(), "x.off")


def test_vectorized_off_reader_on_psb_files_equals_the_line_reader():
    import os
    from pathlib import Path

    from torchakvf.io.off import parse_off_by_lines, parse_plain_off
    root = Path(os.environ.get("TORCHAKVF_PSB", Path(__file__).parents[2] / "shared" / "psb"))
    if not (root / "meshes").is_dir():
        pytest.skip(f"PSB not found at {root} (set TORCHAKVF_PSB)")
    for i in (1, 21, 121, 351):
        raw = gzip.decompress((root / "meshes" / f"{i}.off.gz").read_bytes())
        fast, ref = parse_plain_off(raw), parse_off_by_lines(raw, str(i))
        assert fast is not None and all(np.array_equal(a, b) for a, b in zip(fast, ref))


@pytest.mark.parametrize("text, problem", [
    ("OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", r"vertex line does not hold 3 numbers \(vertex 1, line 4\)"),
    ("# c\nOFF\n3 1 0\n\n0 0 0\n1 0 0\n0 x 0\n3 0 1 2\n", r"\(vertex 2, line 7\)"),
    ("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n4 0 1 2 0\n", r"face 1 has 4 vertices.*face 1, line 7\)"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n# c\nx 0 1 2\n", r"vertex count \(face 0, line 7\)"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2.5\n", r"non-integer vertex index \(face 0, line 6\)"),
])
def test_off_errors_name_the_vertex_or_face_and_its_line(text, problem):
    from torchakvf.io.off import parse_off
    with pytest.raises(ta.MeshError, match=problem):
        parse_off(text.encode(), "x.off")

