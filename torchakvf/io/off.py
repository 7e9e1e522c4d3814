"""The one OFF reader: the header's counts (for a cheap peek) and the whole file (for a load)."""
from __future__ import annotations

import io
from typing import Iterable

import numpy as np

from ..errors import MeshError


def off_counts(lines: Iterable[str], name: str) -> tuple[int, int, int]:
    """(vertices, faces, header lines used) from the first comment-free, non-empty lines of an
    OFF file (``OFF V F E`` on one line, or ``OFF`` then ``V F E``).

    Raises :class:`MeshError` naming ``name`` when the ``OFF`` keyword or the counts are missing
    or not integers: a header that cannot be read is an error, never a guess.
    """
    it = iter(lines)
    first = next(it, None)
    if first is None or not first.upper().startswith("OFF"):
        raise MeshError(name, "missing the 'OFF' header on the first line")
    header, used = first[3:].split(), 1
    if not header:
        second = next(it, None)
        if second is None:
            raise MeshError(name, "missing the 'n_vertices n_faces n_edges' line")
        header, used = second.split(), 2
    try:
        nv, nf = int(header[0]), int(header[1])
    except (ValueError, IndexError):
        raise MeshError(name, f"bad counts line {' '.join(header)!r} (expected 'V F E')") from None
    if nv < 0 or nf < 0:
        raise MeshError(name, f"negative counts in {' '.join(header)!r}")
    return nv, nf, used


def data_lines(text: str) -> list[str]:
    """The lines of an OFF text without ``#`` comments and blank lines."""
    lines = (ln.split("#", 1)[0].strip() for ln in text.splitlines())
    return [ln for ln in lines if ln]


def decode_off(raw: bytes, name: str) -> str:
    try:
        return raw.decode("ascii")
    except UnicodeDecodeError:
        raise MeshError(name, "not a text OFF file (binary or garbage bytes)") from None


def parse_off(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] float64 and triangles [F, 3] int64 of an ASCII OFF file's bytes, faces in
    file order. Strict: a polygon that is not a triangle is an error, not silently split."""
    fast = parse_plain_off(raw)
    if fast is not None:
        return fast
    return parse_off_by_lines(raw, name)


#: Bytes the vectorized reader accepts: printable ASCII, tab, and the two line breaks.
_PLAIN = np.zeros(256, dtype=bool)
_PLAIN[32:127] = True
_PLAIN[[9, 10, 13]] = True
_HASH = ord("#")


def parse_plain_off(raw: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """The same arrays as :func:`parse_off_by_lines`, read with numpy over the whole buffer
    instead of a Python loop over lines (4-5x faster on PSB files); None for any file it does
    not take as is (a comment, another control byte, a header or a line that does not fit), which
    the line reader then parses or rejects with its message.

    Tokens are ``bytes.split()``'s; each data line's token count comes from the bytes (token
    starts binned by line), so every vertex line must hold >= 3 tokens (its first 3 are read)
    and every face line >= 4 with a leading ``3``, exactly as the line reader requires. numpy's
    bytes-to-number casts parse like Python's ``float``/``int``, so the values are identical;
    so does its text reader (:func:`read_sections`, correctly rounded), which takes the usual
    file (3 numbers per vertex line, 4 per face line, plain decimals).
    """
    a = np.frombuffer(raw, dtype=np.uint8)
    if len(a) == 0 or not _PLAIN[a].all() or (a == _HASH).any():
        return None
    newline = (a == 10) | (a == 13)
    space = newline | (a == 32) | (a == 9)
    start = ~space
    start[1:] &= space[:-1]                                  # first byte of each token
    line_of_token = np.cumsum(newline)[start]                # [T] line number of each token
    per_line = np.bincount(line_of_token)
    lines = np.flatnonzero(per_line > 0)                     # [L] physical line of each data line
    per_line = per_line[lines]                               # tokens of each non-blank line
    tokens = raw.split(None, 4)    # the header's (the OFF keyword and the counts are among the first 3)
    if len(per_line) < 2 or tokens[0].upper() != b"OFF":
        return None
    header = tokens[1:per_line[0]] if per_line[0] > 1 else tokens[1:1 + per_line[1]]
    used = 1 if per_line[0] > 1 else 2
    try:
        nv, nf = int(header[0]), int(header[1])
    except (ValueError, IndexError):
        return None
    if nv <= 0 or nf <= 0 or len(per_line) < used + nv + nf:
        return None
    first = np.concatenate([[0], np.cumsum(per_line)])[:-1]   # [L] index of each line's first token
    vlines, flines = first[used:used + nv], first[used + nv:used + nv + nf]
    if (per_line[used:used + nv] < 3).any() or (per_line[used + nv:used + nv + nf] < 4).any():
        return None
    if (per_line[used:used + nv] == 3).all() and (per_line[used + nv:used + nv + nf] == 4).all():
        # The usual file: numpy's C text reader on the two sections (3.5x the token arrays on
        # PSB files), where their bytes are plain decimal numbers (anything else, e.g. "nan",
        # "1_0", goes the token way, which reads it as Python's float/int would)
        starts = np.r_[0, np.flatnonzero(newline) + 1]
        v0, f0 = starts[lines[used]], starts[lines[used + nv]]
        f1 = starts[lines[used + nv + nf - 1] + 1] if lines[used + nv + nf - 1] + 1 < len(starts) else len(a)
        plain = read_sections(raw, a, (v0, f0, f1), nv, nf)
        if plain is not None:
            return plain
    tok = np.array(raw.split())
    try:
        vertices = tok[vlines[:, None] + np.arange(3)].astype(np.float64)
        if not (tok[flines].astype(np.int64) == 3).all():
            return None
        faces = tok[flines[:, None] + np.arange(1, 4)].astype(np.int64)
    except (ValueError, OverflowError):
        return None
    return vertices, faces


#: Bytes of the sections the C reader takes: decimal numbers and blanks (no carriage return).
_DECIMAL = np.zeros(256, dtype=bool)
_DECIMAL[[ord(c) for c in "0123456789.eE+- \t\n"]] = True
_INTEGER = np.zeros(256, dtype=bool)
_INTEGER[[ord(c) for c in "0123456789+- \t\n"]] = True


def read_sections(raw: bytes, a: np.ndarray, cuts: tuple, nv: int, nf: int):
    """(vertices [nv, 3], faces [nf, 3]) from the vertex lines raw[v0:f0] (3 numbers each) and
    the face lines raw[f0:f1] ("3 i j k" each) with numpy's text reader, or None where the
    bytes are not plain decimals or a line does not parse (the token reader decides then)."""
    v0, f0, f1 = (int(c) for c in cuts)
    if not (_DECIMAL[a[v0:f0]].all() and _INTEGER[a[f0:f1]].all()):
        return None
    try:
        vertices = np.loadtxt(io.BytesIO(raw[v0:f0]), dtype=np.float64, ndmin=2)
        faces = np.loadtxt(io.BytesIO(raw[f0:f1]), dtype=np.int64, ndmin=2)
    except (ValueError, OverflowError):
        return None
    if vertices.shape != (nv, 3) or faces.shape != (nf, 4) or not (faces[:, 0] == 3).all():
        return None
    return vertices, np.ascontiguousarray(faces[:, 1:])


def parse_off_by_lines(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`parse_off` line by line: the reference reader, and the one that words the errors
    (naming the vertex or face and its line in the file)."""
    text = decode_off(raw, name)
    lines = data_lines(text)
    nv, nf, used = off_counts(lines, name)
    rest = lines[used:]
    if nv <= 0 or nf <= 0:
        raise MeshError(name, f"empty mesh ({nv} vertices, {nf} faces)")
    if len(rest) < nv + nf:
        raise MeshError(name, f"truncated: header announces {nv} vertices and {nf} faces, "
                              f"file has {len(rest)} data lines")

    def where(kind: str, i: int) -> str:
        return f"{kind} {i}, line {_file_line(text, used + (i if kind == 'vertex' else nv + i))}"

    rows = [ln.split()[:3] for ln in rest[:nv]]
    try:
        vertices = np.array(rows, dtype=np.float64)
    except ValueError:
        vertices = None
    if vertices is None or vertices.shape != (nv, 3):
        bad = next((i for i, r in enumerate(rows) if len(r) < 3 or not _all_floats(r)), 0)
        raise MeshError(name, f"a vertex line does not hold 3 numbers ({where('vertex', bad)})")
    face_tokens = [ln.split() for ln in rest[nv:nv + nf]]
    sizes = np.array([len(t) for t in face_tokens])
    counts = []
    for f, t in enumerate(face_tokens):
        try:
            counts.append(int(t[0]))
        except ValueError:
            raise MeshError(name, "a face line does not start with its vertex count "
                                  f"({where('face', f)})") from None
    counts = np.array(counts)
    not_tri = np.flatnonzero(counts != 3)
    if len(not_tri):
        f = int(not_tri[0])
        raise MeshError(name, f"face {f} has {counts[f]} vertices; only triangle meshes are "
                              f"supported ({len(not_tri)} non-triangle faces; {where('face', f)})")
    if np.any(sizes < 4):
        f = int(np.flatnonzero(sizes < 4)[0])
        raise MeshError(name, f"face {f} lists fewer than 3 indices ({where('face', f)})")
    try:
        faces = np.array([t[1:4] for t in face_tokens], dtype=np.int64)
    except ValueError:
        f = next((i for i, t in enumerate(face_tokens) if not all(_is_int(x) for x in t[1:4])), 0)
        raise MeshError(name, f"a face line holds a non-integer vertex index ({where('face', f)})") from None
    return vertices, faces


def _all_floats(tokens) -> bool:
    try:
        [float(t) for t in tokens]
        return True
    except ValueError:
        return False


def _is_int(token: str) -> bool:
    try:
        int(token)
        return True
    except ValueError:
        return False


def _file_line(text: str, index: int) -> int:
    """The line number in the file (from 1) of data line ``index`` (:func:`data_lines`)."""
    seen = -1
    for number, line in enumerate(text.splitlines(), start=1):
        if line.split("#", 1)[0].strip():
            seen += 1
            if seen == index:
                return number
    return number


def off_face_count(head: bytes, name: str) -> int:
    """Faces declared by the header at the start of an OFF file's (decompressed) bytes."""
    lines: list[str] = []
    for raw in head.split(b"\n", 256)[:256]:   # the header is within the first lines
        line = raw.split(b"#", 1)[0].strip()
        if line:
            lines.append(decode_off(line, name))
        if len(lines) >= 2:
            break
    return off_counts(lines, name)[1]
