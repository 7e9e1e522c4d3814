"""Face counts from a mesh file's header, without parsing the mesh (used to plan batches)."""
from __future__ import annotations

import gzip
import os
import re
from pathlib import Path

from ..errors import MeshError
from .load import mesh_format
from .off import off_face_count

_GZIP_MAGIC = b"\x1f\x8b"
#: Bytes read for a header (OFF, PLY): far more than any header needs.
_HEAD_BYTES = 1 << 16


def _open(path: Path):
    """The file's (decompressed) byte stream; gzip is told by its magic bytes, not the name."""
    with open(path, "rb") as fh:
        magic = fh.read(2)
    return gzip.open(path, "rb") if magic == _GZIP_MAGIC else open(path, "rb")


def peek_face_count(path: str | os.PathLike) -> int | None:
    """The number of faces a mesh file declares, read cheaply.

    OFF: the counts line; PLY: ``element face N``; binary STL: from the file size; ASCII STL
    and OBJ: a byte count of ``facet``/``f`` lines (much cheaper than a parse). Returns None
    only where the format cannot tell cheaply (an ASCII STL or OBJ that cannot be scanned, a
    compressed binary STL). Raises :class:`MeshError` naming the file for a missing or
    unreadable file, an unknown extension, or an OFF/PLY header that does not parse.
    """
    path = Path(path)
    name = str(path)
    fmt, _ = mesh_format(path)
    try:
        with _open(path) as fh:
            if fmt == "off":
                return off_face_count(fh.read(_HEAD_BYTES), name)
            if fmt == "ply":
                return _ply_face_count(fh.read(_HEAD_BYTES), name)
            if fmt == "stl":
                head = fh.read(84)
                if not isinstance(fh, gzip.GzipFile) and len(head) == 84:
                    n = int.from_bytes(head[80:84], "little")
                    if 84 + 50 * n == path.stat().st_size:
                        return n
                data = head + fh.read()
                return data.count(b"facet normal") or None
            return len(re.findall(rb"(?m)^f\s", fh.read()))   # obj
    except FileNotFoundError:
        raise MeshError(name, "file not found") from None
    except IsADirectoryError:
        raise MeshError(name, "is a directory, not a mesh file") from None
    except (OSError, EOFError) as exc:
        raise MeshError(name, f"cannot read file ({getattr(exc, 'strerror', None) or exc})") from None


def _ply_face_count(head: bytes, name: str) -> int:
    if not head.startswith(b"ply"):
        raise MeshError(name, "missing the 'ply' header on the first line")
    for line in head.split(b"\n"):
        parts = line.split()
        if len(parts) == 3 and parts[:2] == [b"element", b"face"]:
            try:
                return int(parts[2])
            except ValueError:
                break
        if line.strip() == b"end_header":
            break
    raise MeshError(name, "PLY header declares no 'element face N'")
