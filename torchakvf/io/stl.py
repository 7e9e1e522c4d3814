"""The STL reader (binary and ASCII): one triangle per facet, in file order, three vertices per
facet (a triangle soup; :func:`torchakvf.mesh.clean_mesh` merges the shared corners).

A binary file is its 84-byte header (80 free bytes, then the triangle count) and 50 bytes per
triangle: a file whose size disagrees with its count is refused ("truncated: header says N
triangles, file has room for M", or the bytes past the last triangle). A file that starts
with ``solid`` and is text is read as ASCII: ``facet [normal nx ny nz]``, ``outer loop``,
three ``vertex x y z`` lines, ``endloop``, ``endfacet``, and ``endsolid`` to close each solid;
any other line, a facet with another number of vertices, or a file that ends inside a solid
is refused with the line it happened on.
"""
from __future__ import annotations

import numpy as np

from ..errors import MeshError
from .tokens import as_float_array

HEADER_BYTES = 84
TRIANGLE_BYTES = 50
_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def is_binary(raw: bytes) -> bool:
    """Whether the bytes are read as a binary STL: the size matches the header's count, or the
    file does not start with ``solid`` followed by text."""
    if len(raw) >= HEADER_BYTES:
        n = int.from_bytes(raw[80:84], "little")
        if HEADER_BYTES + TRIANGLE_BYTES * n == len(raw):
            return True
    if not raw.lstrip()[:5].lower() == b"solid":
        return True
    return b"\x00" in raw or not raw.isascii()


def parse_stl(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [3F, 3] float64 (three per facet) and faces [F, 3] int64 (``[3f, 3f+1, 3f+2]``)
    of an STL file's bytes; see the module docstring for what is refused."""
    if is_binary(raw):
        corners = _binary(raw, name)
    else:
        text = raw.decode("ascii")
        corners = read_plain_ascii(text)
        corners = read_ascii_lines(text, name) if corners is None else corners
    n = len(corners)
    return corners.reshape(-1, 3), np.arange(3 * n, dtype=np.int64).reshape(n, 3)


def binary_face_count(raw_head: bytes, size: int, name: str) -> int:
    """The triangle count of a binary STL from its first 84 bytes and its size in bytes,
    checked against the size."""
    if size < HEADER_BYTES:
        raise MeshError(name, f"truncated: a binary STL starts with an {HEADER_BYTES}-byte header, "
                              f"the file has {size} bytes")
    n = int.from_bytes(raw_head[80:84], "little")
    room = (size - HEADER_BYTES) // TRIANGLE_BYTES
    if n > room:
        raise MeshError(name, f"truncated: header says {n} triangles, file has room for {room}")
    extra = size - HEADER_BYTES - TRIANGLE_BYTES * n
    if extra:
        raise MeshError(name, f"{extra} bytes past the {n} triangles the header says (the file "
                              f"has {size} bytes, {HEADER_BYTES + TRIANGLE_BYTES * n} expected)")
    if n == 0:
        raise MeshError(name, "empty mesh (the binary STL header says 0 triangles)")
    return n


def _binary(raw: bytes, name: str) -> np.ndarray:
    n = binary_face_count(raw[:HEADER_BYTES], len(raw), name)
    records = np.frombuffer(raw, dtype=_RECORD, count=n, offset=HEADER_BYTES)
    return records["corners"].astype(np.float64)


#: Token columns of a facet as most exporters write it (21 tokens on 7 lines), and its corners'.
_FACET_WORDS = {0: "facet", 1: "normal", 5: "outer", 6: "loop", 7: "vertex", 11: "vertex",
                15: "vertex", 19: "endloop", 20: "endfacet"}
_CORNER_COLUMNS = [8, 9, 10, 12, 13, 14, 16, 17, 18]


def read_plain_ascii(text: str) -> np.ndarray | None:
    """:func:`read_ascii_lines`'s corners for the usual file (one solid, every facet in 7 lines
    of the usual 21 tokens), read with numpy instead of line by line; None for any other file,
    which the line reader then reads or refuses with its message."""
    tokens = text.split()
    if not tokens or tokens[0].lower() != "solid" or "facet" not in tokens or "endsolid" not in tokens:
        return None
    start = tokens.index("facet")
    end = len(tokens) - 1 - tokens[::-1].index("endsolid")
    n, rest = divmod(end - start, 21)
    if rest or n == 0 or len(tokens) - end > 2:
        return None
    if sum(1 for line in text.splitlines() if line.strip()) != 2 + 7 * n:
        return None
    table = np.array(tokens[start:end], dtype=object).reshape(n, 21)
    if any((table[:, col] != word).any() for col, word in _FACET_WORDS.items()):
        return None
    try:
        return table[:, _CORNER_COLUMNS].astype(np.float64).reshape(n, 3, 3)
    except (ValueError, OverflowError):
        return None


def read_ascii_lines(text: str, name: str) -> np.ndarray:
    """[F, 3, 3] the corners of each facet of an ASCII STL."""
    corners: list[list[str]] = []
    state, facet_line, current = "file", 0, []
    lines = [(i, ln.split()) for i, ln in enumerate(text.splitlines(), start=1)]
    # a last line without its line break was cut: a fault on it is the truncation
    cut_line = lines[-1][0] if lines and not text.endswith(("\n", "\r")) else -1
    for number, words in lines:
        if not words:
            continue
        key = words[0].lower()
        expect = _NEXT[state]
        if number == cut_line and (key not in expect or (key == "vertex" and len(words) != 4)):
            raise MeshError(name, f"truncated: the file ends inside line {number}"
                                  + (f" (facet {len(corners)})" if state not in ("file", "solid") else ""))
        if key not in expect:
            raise MeshError(name, f"line {number}: {' '.join(words)[:60]!r} where the STL grammar "
                                  f"expects {' or '.join(repr(k) for k in expect)}"
                                  + (f" (facet {len(corners)})" if state not in ("file", "solid") else ""))
        if key == "facet":
            if len(words) not in (1, 5) or (len(words) == 5 and words[1].lower() != "normal"):
                raise MeshError(name, f"line {number}: expected 'facet normal nx ny nz' (facet {len(corners)})")
            facet_line, current = number, []
        elif key == "outer" and [w.lower() for w in words] != ["outer", "loop"]:
            raise MeshError(name, f"line {number}: expected 'outer loop' (facet {len(corners)})")
        elif key == "vertex":
            if len(words) != 4:
                raise MeshError(name, f"line {number}: vertex of facet {len(corners)} does not hold 3 "
                                      "coordinates")
            current.append(words[1:])
        elif key == "endloop" and len(current) != 3:
            raise MeshError(name, f"facet {len(corners)} (line {facet_line}) has {len(current)} "
                                  "vertices; only triangles are supported")
        elif key == "endfacet":
            corners.append(current)
        state = _STATE_AFTER[key] if key != "vertex" else ("loop" if len(current) < 3 else "loop_full")
    if state != "file":
        raise MeshError(name, "truncated: the file ends inside "
                              + (f"facet {len(corners)} (line {facet_line})" if state not in ("solid",)
                                 else f"a solid, after {len(corners)} facets, without 'endsolid'"))
    if not corners:
        raise MeshError(name, "no triangles found in this STL file (no facets)")
    return as_float_array(corners, name, "facet")


#: The keywords each state of the ASCII grammar takes, and the state each keyword leads to.
_NEXT = {"file": ("solid",), "solid": ("facet", "endsolid"), "facet": ("outer",),
         "loop": ("vertex", "endloop"), "loop_full": ("endloop", "vertex"), "endloop": ("endfacet",)}
_STATE_AFTER = {"solid": "solid", "facet": "facet", "outer": "loop", "endloop": "endloop",
                "endfacet": "solid", "endsolid": "file"}


def face_count(raw: bytes, name: str) -> int:
    """Facets an STL file's bytes declare: the binary header's count (checked against the
    size), or the ``facet`` lines of an ASCII file."""
    if is_binary(raw):
        return binary_face_count(raw[:HEADER_BYTES], len(raw), name)
    return len([1 for ln in raw.splitlines() if ln.split()[:1] and ln.split()[0].lower() == b"facet"])


__all__ = ["parse_stl", "is_binary", "binary_face_count", "face_count", "HEADER_BYTES", "TRIANGLE_BYTES"]
