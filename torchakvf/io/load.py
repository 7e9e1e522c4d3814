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
        vertices, faces = _parse_off(raw, name)
    else:
        vertices, faces = _load_with_trimesh(raw, fmt, name)
    return Mesh(vertices, faces, name=name)


def _parse_off(raw: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise MeshError(name, "not a text OFF file (binary or garbage bytes)") from None
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines or not lines[0].upper().startswith("OFF"):
        raise MeshError(name, "missing the 'OFF' header on the first line")
    header = lines[0][3:].split()
    rest = lines[1:]
    if not header:
        if not rest:
            raise MeshError(name, "missing the 'n_vertices n_faces n_edges' line")
        header, rest = rest[0].split(), rest[1:]
    try:
        nv, nf = int(header[0]), int(header[1])
    except (ValueError, IndexError):
        raise MeshError(name, f"bad counts line {' '.join(header)!r} (expected 'V F E')") from None
    if nv <= 0 or nf <= 0:
        raise MeshError(name, f"empty mesh ({nv} vertices, {nf} faces)")
    if len(rest) < nv + nf:
        raise MeshError(name, f"truncated: header announces {nv} vertices and {nf} faces, "
                              f"file has {len(rest)} data lines")
    try:
        vertices = np.array([ln.split()[:3] for ln in rest[:nv]], dtype=np.float64)
    except ValueError:
        raise MeshError(name, "a vertex line does not hold 3 numbers") from None
    if vertices.shape != (nv, 3):
        raise MeshError(name, "a vertex line does not hold 3 numbers")
    face_tokens = [ln.split() for ln in rest[nv:nv + nf]]
    sizes = np.array([len(t) for t in face_tokens])
    try:
        counts = np.array([int(t[0]) for t in face_tokens])
    except ValueError:
        raise MeshError(name, "a face line does not start with its vertex count") from None
    not_tri = np.flatnonzero(counts != 3)
    if len(not_tri):
        f = int(not_tri[0])
        raise MeshError(name, f"face {f} has {counts[f]} vertices; only triangle meshes are "
                              f"supported ({len(not_tri)} non-triangle faces)")
    if np.any(sizes < 4):
        raise MeshError(name, f"face {int(np.flatnonzero(sizes < 4)[0])} lists fewer than 3 indices")
    try:
        faces = np.array([t[1:4] for t in face_tokens], dtype=np.int64)
    except ValueError:
        raise MeshError(name, "a face line holds a non-integer vertex index") from None
    return vertices, faces


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
