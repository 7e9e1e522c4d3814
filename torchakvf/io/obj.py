"""The Wavefront OBJ reader, strict about faces: one triangle read per ``f`` line, in file order.

A face corner may be ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``; indices count from 1, and a
negative index counts back from the last vertex (texture coordinate, normal) defined above
its line. Only the vertex positions are kept. A polygon face (more than 3 corners) is refused,
not split: a split would give a file of N faces more than N labels. Other statements (groups,
materials, lines, points, free-form geometry) are skipped. Refused with a
:class:`~torchakvf.errors.MeshError` naming the line: a vertex that is not 3 numbers, a face
corner that is not an index, an index that is 0 or outside the elements defined.
"""
from __future__ import annotations

import re

import numpy as np

from ..errors import MeshError
from .tokens import as_float_array

_KEYWORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_CORNER = re.compile(r"([+-]?\d+)(?:/([+-]?\d*)(?:/([+-]?\d*))?)?\Z")


def decode_obj(raw: bytes, name: str) -> str:
    if b"\x00" in raw:
        raise MeshError(name, "not a text OBJ file (binary or garbage bytes)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise MeshError(name, "not a text OBJ file (binary or garbage bytes)") from None


def statements(text: str):
    """(line number, keyword, arguments) of each statement, comments and blank lines left out,
    a line ending in a backslash joined to the next (the number is the first line's)."""
    pending, first = "", 0
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0]
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            first = first or number
            continue
        words = (pending + line).split()
        at = first or number
        pending, first = "", 0
        if words:
            yield at, words[0], words[1:]
    if pending.split():
        words = pending.split()
        yield first, words[0], words[1:]


def parse_obj(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] float64 and triangles [F, 3] int64 (0-based) of an OBJ file's bytes, one
    triangle per ``f`` line in file order; see the module docstring for what is refused."""
    vertices: list[list[str]] = []
    corners: list[list[str]] = []      # the three corner tokens of each face
    where: list[tuple[int, int, int, int]] = []   # (line, v, vt, vn defined above it)
    counts = {"v": 0, "vt": 0, "vn": 0}
    for line, key, args in statements(decode_obj(raw, name)):
        if key == "v":
            if not 3 <= len(args) <= 7:
                raise MeshError(name, f"line {line}: vertex 'v {' '.join(args)}' does not hold 3 "
                                      "coordinates")
            vertices.append(args[:3])
            counts["v"] += 1
        elif key in ("vt", "vn"):
            counts[key] += 1
        elif key == "f":
            if len(args) != 3:
                face = len(corners)
                what = "fewer than 3" if len(args) < 3 else str(len(args))
                raise MeshError(name, f"face {face} (line {line}) has {what} corners; only "
                                      "triangle meshes are supported (triangulate the polygons first)")
            corners.append(args)
            where.append((line, counts["v"], counts["vt"], counts["vn"]))
        elif not _KEYWORD.match(key):
            raise MeshError(name, f"line {line}: {key!r} is not an OBJ statement")
    if not corners:
        raise MeshError(name, "no triangles found in this OBJ file (no 'f' lines)")
    if not vertices:
        raise MeshError(name, "no vertices in this OBJ file (no 'v' lines)")
    return _vertices(vertices, name), _faces(corners, where, counts, name)


def _vertices(rows: list[list[str]], name: str) -> np.ndarray:
    return as_float_array(rows, name, "vertex", first=1)


def _faces(corners: list[list[str]], where: list, counts: dict, name: str) -> np.ndarray:
    """[F, 3] 0-based vertex indices; plain ``f i j k`` lines in one numpy cast."""
    n_v = counts["v"]
    try:
        given = np.array(corners, dtype=np.int64)
    except (ValueError, OverflowError):
        given = None
    if given is not None:
        above = np.array([w[1] for w in where], dtype=np.int64)[:, None]
        faces = np.where(given < 0, above + given, given - 1)
        if not ((given == 0) | (faces < 0) | (faces >= n_v)).any():
            return faces
    out = np.empty((len(corners), 3), dtype=np.int64)
    for f, (corner3, (line, v_above, vt_above, vn_above)) in enumerate(zip(corners, where)):
        for c, token in enumerate(corner3):
            m = _CORNER.match(token)
            if m is None:
                raise MeshError(name, f"face {f} (line {line}): corner {token!r} is not "
                                      "'v', 'v/vt', 'v//vn' or 'v/vt/vn' with integer indices")
            out[f, c] = _index(m.group(1), v_above, n_v, "vertex", f, line, name)
            if m.group(2):
                _index(m.group(2), vt_above, counts["vt"], "texture coordinate", f, line, name)
            if m.group(3):
                _index(m.group(3), vn_above, counts["vn"], "normal", f, line, name)
    return out


def _index(token: str, above: int, total: int, what: str, face: int, line: int, name: str) -> int:
    """The 0-based index of an OBJ index token (1-based, or negative: back from ``above``)."""
    i = int(token)
    k = above + i if i < 0 else i - 1
    if i == 0 or not 0 <= k < total:
        if i < 0:
            valid = f"-{above}..-1 here" if above else "none: nothing is defined above this line"
        else:
            valid = f"1..{total}" if total else "none: the file defines none"
        raise MeshError(name, f"face {face} (line {line}): {what} index {i} outside {valid}")
    return k


def face_count(raw: bytes) -> int:
    """The number of ``f`` lines (faces the file declares), counted on the bytes."""
    return len(re.findall(rb"(?m)^[ \t]*f[ \t]", raw))


__all__ = ["parse_obj", "decode_obj", "statements", "face_count"]
