"""Reading meshes from files, face order kept exactly as written: one face read per face the
file declares, or a :class:`~torchakvf.errors.MeshError` saying why not."""
from __future__ import annotations

import gzip
import os
from pathlib import Path

from ..errors import MeshError
from ..mesh.mesh import Mesh
from .gltf import parse_gltf
from .obj import parse_obj
from .off import parse_off
from .ply import parse_ply
from .stl import parse_stl

#: Formats read (each optionally gzip-compressed, ``name.off.gz``).
FORMATS = ("off", "obj", "ply", "stl", "glb", "gltf")


def mesh_format(path: str | os.PathLike) -> tuple[str, bool]:
    """(format, gzipped) of a mesh file name; raises MeshError for an unknown extension."""
    name = Path(path).name.lower()
    gz = name.endswith(".gz")
    if gz:
        name = name[:-3]
    ext = name.rsplit(".", 1)[-1] if "." in name else ""
    if ext not in FORMATS:
        raise MeshError(str(path), f"unknown mesh format '.{ext}' (expected one of "
                                   f"{', '.join('.' + f for f in FORMATS)}, optionally .gz)")
    return ext, gz


def read_mesh_bytes(path: str | os.PathLike) -> bytes:
    """The (decompressed) bytes of a mesh file; MeshError for a missing, unreadable, empty or
    badly compressed file."""
    name = str(path)
    _, gz = mesh_format(path)
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise MeshError(name, "file not found") from None
    except IsADirectoryError:
        raise MeshError(name, "is a directory, not a mesh file") from None
    except OSError as exc:
        raise MeshError(name, f"cannot read file ({exc.strerror or exc})") from None
    if gz:
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, gzip.BadGzipFile):
            raise MeshError(name, "not a valid gzip file (corrupt or truncated)") from None
    if not raw.strip():
        raise MeshError(name, "file is empty")
    return raw


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a triangle mesh (OFF, OBJ, PLY, STL, glTF/GLB; optionally gzipped); the faces keep
    the file's order and count.

    Each format has a strict reader here (:mod:`.off`, :mod:`.obj`, :mod:`.ply`, :mod:`.stl`,
    :mod:`.gltf`): header counts, line shapes and index ranges are checked, a polygon that is
    not a triangle is refused rather than split, so a per-face label file always has one line
    per face of the file. A glTF scene is one mesh, its meshes in world coordinates in the
    order :mod:`.gltf` states. Raises :class:`~torchakvf.errors.MeshError` naming the file and
    the problem (which line, face or index; truncated where).
    """
    name = str(path)
    fmt, _ = mesh_format(path)
    raw = read_mesh_bytes(path)
    if fmt == "off":
        vertices, faces = parse_off(raw, name)
    elif fmt == "ply":
        vertices, faces = parse_ply(raw, name)
    elif fmt == "obj":
        vertices, faces = parse_obj(raw, name)
    elif fmt == "stl":
        vertices, faces = parse_stl(raw, name)
    else:
        vertices, faces = parse_gltf(raw, name, folder=Path(path).parent)
    return Mesh(vertices, faces, name=name)


__all__ = ["FORMATS", "mesh_format", "read_mesh_bytes", "load_mesh"]
