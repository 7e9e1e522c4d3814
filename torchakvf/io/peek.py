"""Face counts from a mesh file's header, without parsing the mesh (used to plan batches)."""
from __future__ import annotations

import gzip
import os
from pathlib import Path

from ..errors import MeshError
from . import stl
from .gltf import face_count as gltf_face_count
from .gltf import glb_json_size
from .load import mesh_format
from .obj import face_count as obj_face_count
from .off import off_face_count
from .ply import face_count as ply_face_count

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

    OFF: the counts line; PLY: ``element face N``; binary STL: the header's count, checked
    against the file size; ASCII STL and OBJ: a byte count of ``facet``/``f`` lines (much
    cheaper than a parse); glTF/GLB: the index counts of its JSON. Raises :class:`MeshError`
    naming the file for a missing or unreadable file, an unknown extension, or a header that
    does not parse (the load then says the same, or more).
    """
    path = Path(path)
    name = str(path)
    fmt, _ = mesh_format(path)
    try:
        with _open(path) as fh:
            if fmt == "off":
                return off_face_count(fh.read(_HEAD_BYTES), name)
            if fmt == "ply":
                return ply_face_count(fh.read(_HEAD_BYTES), name)
            if fmt == "stl":
                head = fh.read(stl.HEADER_BYTES)
                if not isinstance(fh, gzip.GzipFile) and len(head) == stl.HEADER_BYTES:
                    n = int.from_bytes(head[80:84], "little")
                    if stl.HEADER_BYTES + stl.TRIANGLE_BYTES * n == path.stat().st_size:
                        return n
                return stl.face_count(head + fh.read(), name)
            if fmt in ("glb", "gltf"):
                head = fh.read(20)
                size = glb_json_size(head)
                return gltf_face_count(head + fh.read() if size is None else fh.read(size), name)
            return obj_face_count(fh.read())
    except FileNotFoundError:
        raise MeshError(name, "file not found") from None
    except IsADirectoryError:
        raise MeshError(name, "is a directory, not a mesh file") from None
    except (OSError, EOFError) as exc:
        raise MeshError(name, f"cannot read file ({getattr(exc, 'strerror', None) or 'corrupt data'})") from None
