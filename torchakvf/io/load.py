"""Reading meshes from files, face order kept exactly as written."""
from __future__ import annotations

import gzip
import io
import os
import re
from pathlib import Path

import numpy as np

from ..errors import MeshError
from ..mesh.mesh import Mesh
from .off import parse_off

#: Formats read (each optionally gzip-compressed, ``name.off.gz``).
FORMATS = ("off", "obj", "ply", "stl")


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


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a triangle mesh; the faces keep the file's order and count.

    OFF files are parsed here (strictly: a polygon that is not a triangle is an error, not
    silently split); OBJ, PLY and STL go through trimesh with ``process=False`` so nothing is
    merged or reordered. Raises :class:`~torchakvf.errors.MeshError` naming the file and the
    problem for missing, unreadable or malformed files.
    """
    name = str(path)
    fmt, gz = mesh_format(path)
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
        except (OSError, EOFError, gzip.BadGzipFile) as exc:
            raise MeshError(name, f"not a valid gzip file ({exc})") from None
    if not raw.strip():
        raise MeshError(name, "file is empty")
    if fmt == "off":
        vertices, faces = parse_off(raw, name)
    else:
        vertices, faces = _load_with_trimesh(raw, fmt, name)
    return Mesh(vertices, faces, name=name)


_OBJ_FACE = re.compile(rb"^f\s+(.*)$", re.MULTILINE)


def _load_with_trimesh(raw: bytes, fmt: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    if fmt == "obj":
        # trimesh splits polygons silently; a per-face label file would then be misaligned.
        for match in _OBJ_FACE.finditer(raw):
            if len(match.group(1).split()) != 3:
                raise MeshError(name, "has non-triangle faces (OBJ polygon with "
                                      f"{len(match.group(1).split())} vertices); only triangle "
                                      "meshes are supported")
    try:
        loaded = trimesh.load(io.BytesIO(raw), file_type=fmt, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types on malformed input
        raise MeshError(name, f"cannot parse as {fmt.upper()} ({type(exc).__name__}: {exc})") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))))
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))))
    if faces.ndim != 2 or len(faces) == 0 or len(vertices) == 0:
        raise MeshError(name, f"no triangles found in this {fmt.upper()} file")
    return vertices, faces
