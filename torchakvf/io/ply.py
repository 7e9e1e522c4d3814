"""The PLY reader (ASCII and binary, little or big endian), strict about the header's promises.

The header's element counts and property layout are checked against the data: in an ASCII
file every element is one line holding exactly its properties' numbers; in a binary file the
data must fill the file to the last byte. A face that is not a triangle, a vertex index out
of range, a short or long line, a truncated file or bytes past the last element are refused
with a :class:`~torchakvf.errors.MeshError` saying which face, which line or which byte.
Faces keep the file's order: one face read per face the header declares.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import MeshError

#: PLY scalar type names (both spellings) -> numpy type code.
SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
#: Names a face's vertex list goes by.
FACE_LIST_NAMES = ("vertex_indices", "vertex_index")
_ENCODINGS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class Property:
    name: str
    dtype: str                 # numpy type code of the value (the items, for a list)
    count_dtype: str | None    # numpy type code of a list's length; None for a scalar

    @property
    def is_list(self) -> bool:
        return self.count_dtype is not None


@dataclass
class Element:
    name: str
    count: int
    properties: list[Property] = field(default_factory=list)


@dataclass
class Header:
    encoding: str              # "ascii", "binary_little_endian" or "binary_big_endian"
    elements: list[Element]
    size: int                  # bytes of the header, through the end_header line
    lines: int                 # lines of the header


def parse_header(raw: bytes, name: str) -> Header:
    """The header of a PLY file's bytes; raises :class:`MeshError` on any line it cannot take."""
    if not raw.startswith(b"ply"):
        raise MeshError(name, "missing the 'ply' header on the first line")
    end = re.search(rb"(?m)^end_header[ \t]*\r?(\n|$)", raw)
    if end is None:
        raise MeshError(name, "PLY header has no 'end_header' line")
    try:
        text = raw[:end.start()].decode("ascii")
    except UnicodeDecodeError:
        raise MeshError(name, "PLY header holds bytes that are not text") from None
    encoding, elements = None, []
    lines = text.splitlines()
    for number, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        where = f"header line {number} {line.strip()!r}"
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _ENCODINGS:
                raise MeshError(name, f"{where}: expected 'format ascii|binary_little_endian|"
                                      "binary_big_endian 1.0'")
            encoding = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise MeshError(name, f"{where}: expected 'element <name> <count>'")
            if any(e.name == words[1] for e in elements):
                raise MeshError(name, f"{where}: a second element '{words[1]}'")
            elements.append(Element(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise MeshError(name, f"{where}: a property before any element")
            prop = _property(words, where, name)
            if any(p.name == prop.name for p in elements[-1].properties):
                raise MeshError(name, f"{where}: a second property '{prop.name}' in element "
                                      f"'{elements[-1].name}'")
            elements[-1].properties.append(prop)
        else:
            raise MeshError(name, f"{where}: not a PLY header line")
    if encoding is None:
        raise MeshError(name, "PLY header has no 'format' line")
    return Header(encoding, elements, end.end(), len(lines) + 1)


def _property(words: list[str], where: str, name: str) -> Property:
    if len(words) == 3 and words[1] in SCALAR_TYPES:
        return Property(words[2], SCALAR_TYPES[words[1]], None)
    if len(words) == 5 and words[1] == "list" and words[2] in SCALAR_TYPES and words[3] in SCALAR_TYPES:
        if SCALAR_TYPES[words[2]][0] not in "iu":
            raise MeshError(name, f"{where}: a list's length type must be an integer type")
        return Property(words[4], SCALAR_TYPES[words[3]], SCALAR_TYPES[words[2]])
    raise MeshError(name, f"{where}: expected 'property <type> <name>' or 'property list "
                          "<length type> <item type> <name>' with a known type")


def face_count(head: bytes, name: str) -> int:
    """Faces the header at the start of a PLY file's bytes declares (``element face N``)."""
    for element in parse_header(head, name).elements:
        if element.name == "face":
            return element.count
    raise MeshError(name, "PLY header declares no 'element face N'")


def parse_ply(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] float64 and triangles [F, 3] int64 of a PLY file's bytes, faces in file
    order; see the module docstring for what is refused."""
    header = parse_header(raw, name)
    vertex, face = _mesh_elements(header, name)
    if header.encoding == "ascii":
        values = _read_ascii(raw[header.size:], header, name)
    else:
        values = _read_binary(raw[header.size:], header, name)
    xyz = values[vertex.name]
    vertices = np.stack([xyz[p] for p in "xyz"], axis=1).astype(np.float64)
    faces = values[face.name]
    _check_index_range(faces, len(vertices), header, name)
    return vertices, faces


def _mesh_elements(header: Header, name: str) -> tuple[Element, Element]:
    found = {e.name: e for e in header.elements}
    vertex, face = found.get("vertex"), found.get("face")
    if vertex is None or face is None:
        raise MeshError(name, "PLY header must declare 'element vertex' and 'element face'")
    names = [p.name for p in vertex.properties]
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise MeshError(name, f"PLY vertices have no '{missing[0]}' property")
    for c in "xyz":
        if vertex.properties[names.index(c)].is_list:
            raise MeshError(name, f"PLY vertex property '{c}' is a list, not a number")
    lists = [p for p in face.properties if p.is_list and p.name in FACE_LIST_NAMES]
    if not lists:
        raise MeshError(name, "PLY faces have no 'property list ... vertex_indices'")
    if lists[0].dtype[0] not in "iu":
        raise MeshError(name, "PLY face vertex indices are not an integer type")
    if vertex.count == 0 or face.count == 0:
        raise MeshError(name, f"empty mesh ({vertex.count} vertices, {face.count} faces)")
    return vertex, face


def _face_list(element: Element) -> Property:
    return next(p for p in element.properties if p.is_list and p.name in FACE_LIST_NAMES)


def _check_index_range(faces: np.ndarray, n_vertices: int, header: Header, name: str) -> None:
    bad = (faces < 0) | (faces >= n_vertices)
    if bad.any():
        f = int(np.flatnonzero(bad.any(axis=1))[0])
        where = f"face {f}"
        if header.encoding == "ascii":
            where += f" (line {_ascii_line_of(header, 'face', f)})"
        raise MeshError(name, f"{where} has vertex index {int(faces[f][bad[f]][0])} outside "
                              f"0..{n_vertices - 1}")


def _ascii_line_of(header: Header, element_name: str, index: int) -> int:
    """The file line of an ASCII element instance (the reader requires one line each and no
    blank lines inside the data, so this is exact)."""
    line = header.lines
    for e in header.elements:
        if e.name == element_name:
            return line + index + 1
        line += e.count
    return line


# ---- ASCII ------------------------------------------------------------------------------------

def _read_ascii(body: bytes, header: Header, name: str) -> dict:
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError:
        raise MeshError(name, "ASCII PLY data holds bytes that are not text") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    declared = sum(e.count for e in header.elements)
    if len(lines) < declared:
        have = ", ".join(f"{e.count} {e.name}" for e in header.elements)
        raise MeshError(name, f"truncated: header declares {declared} data lines ({have}), "
                              f"file has {len(lines)}")
    if len(lines) > declared:
        extra = len(lines) - declared
        raise MeshError(name, f"{extra} data line{'s' if extra > 1 else ''} past the {declared} the "
                              f"header declares (first: line {header.lines + declared + 1}); the "
                              "header's counts do not match the data")
    values, start = {}, 0
    for element in header.elements:
        chunk = lines[start:start + element.count]
        values[element.name] = _ascii_element(chunk, element, header.lines + start + 1, name)
        start += element.count
    return values


def _ascii_element(lines: list[str], element: Element, first_line: int, name: str):
    """The values of one element's lines: {x: [V], y, z} for vertices, [F, 3] for faces, None
    for other elements (checked, not kept)."""
    rows = [ln.split() for ln in lines]
    widths = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    if not any(p.is_list for p in element.properties):
        expected = len(element.properties)
        bad = np.flatnonzero(widths != expected)
        if len(bad):
            i = int(bad[0])
            raise MeshError(name, f"line {first_line + i} ({element.name} {i}) holds {widths[i]} "
                                  f"numbers, the header declares {expected}")
        if element.name != "vertex":
            return None
        out = {}
        for j, p in enumerate(element.properties):
            if p.name in ("x", "y", "z"):
                out[p.name] = _ascii_numbers([r[j] for r in rows], first_line, element.name, name, float)
        return out
    if element.name != "face":
        for i, r in enumerate(rows):
            _ascii_row_with_lists(r, element, first_line + i, i, name)
        return None
    return _ascii_faces(rows, widths, element, first_line, name)


def _ascii_numbers(tokens: list[str], first_line: int, what: str, name: str, kind) -> np.ndarray:
    try:
        return np.array(tokens, dtype=np.float64 if kind is float else np.int64)
    except (ValueError, OverflowError):
        for i, t in enumerate(tokens):
            try:
                kind(t)
            except (ValueError, OverflowError):
                noun = "a number" if kind is float else "an integer"
                raise MeshError(name, f"line {first_line + i} ({what} {i}): {t!r} is not {noun}") from None
        raise


def _ascii_faces(rows, widths, element: Element, first_line: int, name: str) -> np.ndarray:
    props = element.properties
    target = _face_list(element)
    if len(props) == 1 and len(rows) and (widths == 4).all():
        try:
            table = np.array(rows, dtype=np.int64)
        except (ValueError, OverflowError):
            table = None
        if table is not None and (table[:, 0] == 3).all():
            return np.ascontiguousarray(table[:, 1:])
    faces = np.empty((len(rows), 3), dtype=np.int64)
    for i, r in enumerate(rows):
        faces[i] = _ascii_row_with_lists(r, element, first_line + i, i, name)[target.name]
    return faces


def _ascii_row_with_lists(tokens: list[str], element: Element, line: int, index: int, name: str) -> dict:
    """One element line read property by property; a face's vertex list must hold 3 indices."""
    where = f"line {line} ({element.name} {index})"
    pos, out = 0, {}
    for p in element.properties:
        if not p.is_list:
            _ascii_token(tokens, pos, where, p, name, float if p.dtype[0] == "f" else int)
            pos += 1
            continue
        n = _ascii_token(tokens, pos, where, p, name, int, "length")
        if n < 0:
            raise MeshError(name, f"{where}: negative list length {n} for '{p.name}'")
        if element.name == "face" and p.name in FACE_LIST_NAMES and n != 3:
            raise MeshError(name, f"face {index} ({where[:where.index(' (')]}) has {n} vertices; "
                                  "only triangle meshes are supported")
        kind = float if p.dtype[0] == "f" else int
        out[p.name] = [_ascii_token(tokens, pos + 1 + k, where, p, name, kind) for k in range(n)]
        pos += 1 + n
    if pos != len(tokens):
        raise MeshError(name, f"{where} holds {len(tokens)} numbers, its properties take {pos}")
    return out


def _ascii_token(tokens, pos, where, prop: Property, name: str, kind, what: str = "value"):
    if pos >= len(tokens):
        raise MeshError(name, f"{where} ends before the {what} of '{prop.name}'")
    try:
        return kind(tokens[pos])
    except ValueError:
        noun = "a number" if kind is float else "an integer"
        raise MeshError(name, f"{where}: {tokens[pos]!r} ({prop.name}) is not {noun}") from None


# ---- binary -----------------------------------------------------------------------------------

def _read_binary(body: bytes, header: Header, name: str) -> dict:
    order = _ENCODINGS[header.encoding]
    values, offset = {}, 0
    for element in header.elements:
        values[element.name], offset = _binary_element(body, offset, element, order, header, name)
    if offset != len(body):
        raise MeshError(name, f"{len(body) - offset} bytes past the last element the header "
                              f"declares (data ends at byte {header.size + offset} of "
                              f"{header.size + len(body)}); the header's counts do not match the data")
    return values


def _binary_element(body: bytes, offset: int, element: Element, order: str, header: Header, name: str):
    """(values, offset after the element): one structured read when each list has the length
    of the element's first instance (a triangle mesh's faces), a walk through it otherwise
    (:func:`_walk_element`)."""
    lengths = _first_lengths(body, offset, element, order, header, name)
    dtype = _fixed_dtype(element, lengths, order)
    need = dtype.itemsize * element.count
    if offset + need > len(body):
        if any(p.is_list for p in element.properties):
            return _walk_element(body, offset, element, order, header, name)   # says where it ends
        room = (len(body) - offset) // dtype.itemsize if dtype.itemsize else 0
        raise MeshError(name, f"truncated: header declares {element.count} {element.name} "
                              f"elements, the file has room for {room} (data ends at byte "
                              f"{header.size + len(body)})")
    table = np.frombuffer(body, dtype=dtype, count=element.count, offset=offset)
    for p in element.properties:
        if p.is_list:
            off = np.flatnonzero(table[f"{p.name}#n"] != lengths[p.name])
            if len(off):
                i = int(off[0])
                if element.name == "face" and p.name in FACE_LIST_NAMES:
                    raise MeshError(name, f"face {i} has {int(table[f'{p.name}#n'][i])} vertices; "
                                          "only triangle meshes are supported")
                if element.name == "vertex":
                    raise MeshError(name, f"vertex {i}'s list '{p.name}' differs in length from "
                                          "vertex 0's; this reader takes vertex lists of one length")
                return _walk_element(body, offset, element, order, header, name)
    return _element_values(table, element), offset + need


def _fixed_dtype(element: Element, lengths: dict, order: str) -> np.dtype:
    fields = []
    for p in element.properties:
        if p.is_list:
            fields.append((f"{p.name}#n", order + p.count_dtype))
            fields += [(f"{p.name}#{k}", order + p.dtype) for k in range(lengths[p.name])]
        else:
            fields.append((p.name, order + p.dtype))
    return np.dtype(fields)


def _first_lengths(body: bytes, offset: int, element: Element, order: str, header: Header, name: str) -> dict:
    """The length of each list property in the element's first instance."""
    lengths, pos = {}, offset
    if element.count == 0:
        return {p.name: 0 for p in element.properties if p.is_list}
    for p in element.properties:
        if not p.is_list:
            pos += np.dtype(p.dtype).itemsize
            continue
        n = _read_scalar(body, pos, order + p.count_dtype, element, 0, header, name)
        if element.name == "face" and p.name in FACE_LIST_NAMES and n != 3:
            raise MeshError(name, f"face 0 has {n} vertices; only triangle meshes are supported")
        lengths[p.name] = n
        pos += np.dtype(p.count_dtype).itemsize + n * np.dtype(p.dtype).itemsize
        if pos > len(body):
            raise MeshError(name, _ends_inside(element, 0, header, body)
                                  + f" (its list '{p.name}' says {n} items)")
    return lengths


def _read_scalar(body, pos, dtype, element: Element, index: int, header: Header, name: str) -> int:
    size = np.dtype(dtype).itemsize
    if pos + size > len(body):
        raise MeshError(name, _ends_inside(element, index, header, body))
    n = int(np.frombuffer(body, dtype=dtype, count=1, offset=pos)[0])
    if n < 0:
        raise MeshError(name, f"{element.name} {index} has a negative list length ({n})")
    return n


def _walk_element(body: bytes, offset: int, element: Element, order: str, header: Header, name: str):
    """An element whose lists vary in length, one instance at a time: (the faces' triangles
    [F, 3] for the face element, else None; offset after the element)."""
    pos = offset
    triangles = [] if element.name == "face" else None
    for i in range(element.count):
        for p in element.properties:
            if not p.is_list:
                pos += np.dtype(p.dtype).itemsize
                continue
            n = _read_scalar(body, pos, order + p.count_dtype, element, i, header, name)
            pos += np.dtype(p.count_dtype).itemsize
            if triangles is not None and p.name in FACE_LIST_NAMES:
                if n != 3:
                    raise MeshError(name, f"face {i} has {n} vertices; only triangle meshes are supported")
                if pos + 3 * np.dtype(p.dtype).itemsize <= len(body):
                    triangles.append(np.frombuffer(body, dtype=order + p.dtype, count=3, offset=pos))
            pos += n * np.dtype(p.dtype).itemsize
        if pos > len(body):
            raise MeshError(name, _ends_inside(element, i, header, body))
    if triangles is not None:
        triangles = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    return triangles, pos


def _ends_inside(element: Element, index: int, header: Header, body: bytes) -> str:
    return (f"truncated: header declares {element.count} {element.name} elements, the data ends "
            f"inside {element.name} {index} (at byte {header.size + len(body)})")


def _element_values(table: np.ndarray, element: Element):
    if element.name == "vertex":
        return {c: table[c] for c in "xyz"}
    if element.name == "face":
        p = _face_list(element)
        return np.stack([table[f"{p.name}#{k}"] for k in range(3)], axis=1).astype(np.int64)
    return None


__all__ = ["parse_ply", "parse_header", "face_count", "Header", "Element", "Property",
           "SCALAR_TYPES", "FACE_LIST_NAMES"]
