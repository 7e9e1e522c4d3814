"""The glTF 2.0 reader (``.glb`` binary, ``.gltf`` JSON with embedded or side-by-side buffers):
the whole scene as one triangle mesh in world coordinates.

Face order (what a label file of a ``.glb`` follows): the scene's nodes depth first, each
node before its children, siblings in the order the file lists them (the default scene's
``nodes``, or else every root node in file order); for each node with a mesh, its primitives
in order; for each primitive, its triangles in order (strips and fans are expanded to their
triangles, point and line primitives carry no faces and are skipped). A mesh used by two
nodes appears twice. Each node's transform (``matrix`` or translation/rotation/scale, times
its parents') is applied to its vertices. Vertices are not merged: each primitive instance
brings its own (:func:`torchakvf.mesh.clean_mesh` merges equal ones).

Anything the reader cannot follow (a missing or out-of-range accessor, a buffer too short
for what reads it, a compression extension it does not decode) is refused with a
:class:`~torchakvf.errors.MeshError` naming the part of the file.
"""
from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

from ..errors import MeshError

_COMPONENT = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_TRIANGLES, _STRIP, _FAN = 4, 5, 6
_GLB_MAGIC, _JSON_CHUNK, _BIN_CHUNK = b"glTF", 0x4E4F534A, 0x004E4942


class _Bad(Exception):
    """A problem with the file, in the user's terms (turned into a MeshError naming the file)."""


def parse_gltf(raw: bytes, name: str, folder: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] float64 (world coordinates) and triangles [F, 3] int64 of a glTF file's
    bytes (GLB, or glTF JSON whose external buffers are looked up in ``folder``), faces in the
    order of the module docstring."""
    try:
        doc, binary = _document(raw, name)
        reader = _Reader(doc, binary, folder)
        vertices, faces = [], []
        offset = 0
        for where, matrix, primitive in _primitive_instances(doc):
            v, f = reader.triangles(primitive, where)
            if f is None:
                continue
            vertices.append(v @ matrix[:3, :3].T + matrix[:3, 3])
            faces.append(f + offset)
            offset += len(v)
    except _Bad as exc:
        raise MeshError(name, str(exc)) from None
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, OverflowError):
        raise MeshError(name, "malformed glTF: a field of its JSON has an unexpected type or "
                              "value") from None
    if not faces or sum(len(f) for f in faces) == 0:
        raise MeshError(name, "no triangles found in this glTF file's scene")
    return np.concatenate(vertices), np.concatenate(faces)


def glb_json_size(head: bytes) -> int | None:
    """Bytes of a GLB's JSON chunk from the file's first 20 bytes (None: not a GLB), so a
    caller can read the JSON without the binary chunk."""
    if len(head) < 20 or head[:4] != _GLB_MAGIC:
        return None
    return struct.unpack_from("<I", head, 12)[0]


def face_count(raw: bytes, name: str) -> int:
    """Triangles the scene of a glTF file's bytes declares (from the JSON: index or position
    counts), without reading the buffers. ``raw`` may also be a GLB's JSON chunk alone."""
    try:
        doc, _ = _document(raw, name)
        total = 0
        for where, _, primitive in _primitive_instances(doc):
            total += _Reader(doc, None, None).declared_triangles(primitive, where)
        return total
    except _Bad as exc:
        raise MeshError(name, str(exc)) from None
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, OverflowError):
        raise MeshError(name, "malformed glTF: a field of its JSON has an unexpected type or "
                              "value") from None


def _document(raw: bytes, name: str) -> tuple[dict, bytes | None]:
    """(the glTF JSON, the GLB's binary chunk or None) of a file's bytes."""
    if raw[:4] == _GLB_MAGIC:
        text, binary = _glb_chunks(raw)
    else:
        text, binary = raw, None
    try:
        doc = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        raise _Bad("not a glTF file: its JSON does not parse" if binary is not None or raw[:4] == _GLB_MAGIC
                   else "not a glTF file (neither GLB bytes nor glTF JSON)") from None
    if not isinstance(doc, dict):
        raise _Bad("not a glTF file: its JSON is not an object")
    version = str(_get(doc, "asset", dict, "the file").get("version", ""))
    if not version.startswith("2."):
        raise _Bad(f"glTF version {version or '(none)'} is not read (glTF 2.0 is)")
    unsupported = [e for e in doc.get("extensionsRequired", []) or [] if isinstance(e, str)]
    if unsupported:
        raise _Bad(f"needs extension {unsupported[0]} (e.g. mesh compression), which this reader "
                   "does not decode; export the file without it")
    return doc, binary


def _glb_chunks(raw: bytes) -> tuple[bytes, bytes | None]:
    if len(raw) < 20:
        raise _Bad(f"truncated: a GLB starts with a 20-byte header, the file has {len(raw)} bytes")
    version, length = struct.unpack_from("<II", raw, 4)
    if version != 2:
        raise _Bad(f"GLB version {version} is not read (version 2 is)")
    if length != len(raw):
        what = "truncated: " if length > len(raw) else ""
        raise _Bad(f"{what}the GLB header says {length} bytes, the file has {len(raw)}")
    chunks, pos = [], 12
    while pos < len(raw):
        if pos + 8 > len(raw):
            raise _Bad(f"truncated: GLB chunk header at byte {pos} is cut off")
        size, kind = struct.unpack_from("<II", raw, pos)
        if pos + 8 + size > len(raw):
            raise _Bad(f"truncated: GLB chunk at byte {pos} says {size} bytes, "
                       f"{len(raw) - pos - 8} are left")
        chunks.append((kind, raw[pos + 8:pos + 8 + size]))
        pos += 8 + size
    if not chunks or chunks[0][0] != _JSON_CHUNK:
        raise _Bad("the GLB's first chunk is not its JSON")
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _BIN_CHUNK else None
    return chunks[0][1], binary


def _get(obj: dict, key: str, kind, where: str, default=None):
    value = obj.get(key, default) if isinstance(obj, dict) else None
    if value is None and default is None:
        raise _Bad(f"{where} has no '{key}'")
    if kind is int and isinstance(value, bool) or not isinstance(value, kind):
        raise _Bad(f"{where}: '{key}' is not {_KIND_NAMES.get(kind, kind.__name__)}")
    return value


_KIND_NAMES = {int: "an integer", list: "a list", dict: "an object", str: "a string"}


def _item(doc: dict, key: str, index, where: str) -> dict:
    items = doc.get(key)
    if not isinstance(items, list) or not isinstance(index, int) or not 0 <= index < len(items) \
            or not isinstance(items[index], dict):
        size = len(items) if isinstance(items, list) else 0
        singular = {"meshes": "mesh", "accessors": "accessor"}.get(key, key[:-1])
        raise _Bad(f"{where} refers to {singular} {index!r}, the file has {size} {key}")
    return items[index]


def _primitive_instances(doc: dict):
    """(where, world matrix [4, 4], primitive) of each mesh primitive the scene draws, in the
    face order of the module docstring."""
    nodes = doc.get("nodes", []) or []
    if not isinstance(nodes, list):
        raise _Bad("'nodes' is not a list")
    scenes = doc.get("scenes")
    if isinstance(scenes, list) and scenes:
        scene_index = doc.get("scene", 0)
        roots = _get(_item(doc, "scenes", scene_index, "the file's 'scene'"), "nodes", list,
                     f"scene {scene_index}", default=[])
    else:
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", []) or []
                    if isinstance(c, int)}
        roots = [i for i in range(len(nodes)) if i not in children]
    stack = [(r, np.eye(4), 0) for r in reversed(roots)]
    while stack:
        index, parent, depth = stack.pop()
        if depth > len(nodes):
            raise _Bad(f"node {index} is its own ancestor (a cycle in the node tree)")
        node = _item(doc, "nodes", index, "the scene")
        matrix = parent @ _local_matrix(node, f"node {index}")
        if "mesh" in node:
            mesh = _item(doc, "meshes", node["mesh"], f"node {index}")
            for p, primitive in enumerate(_get(mesh, "primitives", list, f"mesh {node['mesh']}")):
                yield f"mesh {node['mesh']} primitive {p}", matrix, primitive
        children = _get(node, "children", list, f"node {index}", default=[])
        stack += [(c, matrix, depth + 1) for c in reversed(children)]


def _local_matrix(node: dict, where: str) -> np.ndarray:
    try:
        if "matrix" in node:
            m = np.array(node["matrix"], dtype=np.float64)
            if m.shape != (16,):
                raise _Bad(f"{where}: 'matrix' does not hold 16 numbers")
            return m.reshape(4, 4).T                     # glTF matrices are column-major
        t = np.array(node.get("translation", [0, 0, 0]), dtype=np.float64)
        x, y, z, w = np.array(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
        s = np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
    except (TypeError, ValueError):
        raise _Bad(f"{where}: its transform does not hold numbers") from None
    if t.shape != (3,) or s.shape != (3,):
        raise _Bad(f"{where}: translation and scale must hold 3 numbers")
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    out = np.eye(4)
    out[:3, :3] = r * s
    out[:3, 3] = t
    return out


class _Reader:
    """Reads accessors of one document (its buffers loaded once each)."""

    def __init__(self, doc: dict, binary: bytes | None, folder: Path | None):
        self.doc, self.binary, self.folder = doc, binary, folder
        self.buffers: dict[int, bytes] = {}

    def declared_triangles(self, primitive: dict, where: str) -> int:
        mode = _get(primitive, "mode", int, where, default=_TRIANGLES)
        if mode not in (_TRIANGLES, _STRIP, _FAN):
            return 0
        key = "indices" if "indices" in primitive else None
        if key is None:
            attributes = _get(primitive, "attributes", dict, where)
            acc = _item(self.doc, "accessors", attributes.get("POSITION"), f"{where} POSITION")
        else:
            acc = _item(self.doc, "accessors", primitive["indices"], f"{where} indices")
        n = _get(acc, "count", int, f"{where}'s accessor")
        if mode == _TRIANGLES:
            if n % 3:
                raise _Bad(f"{where} lists {n} corners, not a multiple of 3 (triangles)")
            return n // 3
        return max(n - 2, 0)

    def triangles(self, primitive: dict, where: str):
        """(vertices [V, 3], faces [T, 3]) of one primitive; (None, None) for points and lines."""
        n_tri = self.declared_triangles(primitive, where)
        if _get(primitive, "mode", int, where, default=_TRIANGLES) not in (_TRIANGLES, _STRIP, _FAN):
            return None, None
        attributes = _get(primitive, "attributes", dict, where)
        if "POSITION" not in attributes:
            raise _Bad(f"{where} has no POSITION attribute")
        positions = self.accessor(attributes["POSITION"], f"{where} POSITION", width=3)
        if "indices" in primitive:
            index = self.accessor(primitive["indices"], f"{where} indices", width=1, integer=True)
            index = index[:, 0].astype(np.int64)
        else:
            index = np.arange(len(positions), dtype=np.int64)
        faces = _corner_triangles(index, _get(primitive, "mode", int, where, default=_TRIANGLES))
        if len(faces) != n_tri:
            raise _Bad(f"{where}: {len(faces)} triangles read, {n_tri} declared")
        bad = (faces < 0) | (faces >= len(positions))
        if bad.any():
            t = int(np.flatnonzero(bad.any(axis=1))[0])
            raise _Bad(f"{where}: triangle {t} has vertex index {int(faces[t][bad[t]][0])} outside "
                       f"0..{len(positions) - 1}")
        return positions.astype(np.float64), faces

    def accessor(self, index, where: str, width: int, integer: bool = False) -> np.ndarray:
        acc = _item(self.doc, "accessors", index, where)
        where = f"accessor {index} ({where})"
        if "sparse" in acc:
            raise _Bad(f"{where} is sparse, which this reader does not read")
        ctype = _get(acc, "componentType", int, where)
        if ctype not in _COMPONENT or (integer and ctype == 5126):
            raise _Bad(f"{where}: component type {ctype} is not " + ("an integer type" if integer else "known"))
        if _WIDTH.get(acc.get("type")) != width:
            raise _Bad(f"{where}: type {acc.get('type')!r}, expected "
                       + ("SCALAR" if width == 1 else "VEC3"))
        count = _get(acc, "count", int, where)
        dtype = np.dtype("<" + _COMPONENT[ctype])
        if "bufferView" not in acc:
            return np.zeros((count, width), dtype=dtype)
        view = _item(self.doc, "bufferViews", acc["bufferView"], where)
        data = self.view_bytes(view, acc["bufferView"])
        offset = _get(acc, "byteOffset", int, where, default=0)
        stride = _get(view, "byteStride", int, f"buffer view {acc['bufferView']}", default=0) or dtype.itemsize * width
        need = offset + stride * (count - 1) + dtype.itemsize * width if count else 0
        if count < 0 or offset < 0 or stride < dtype.itemsize * width or need > len(data):
            raise _Bad(f"truncated: {where} reads {need} bytes of buffer view "
                       f"{acc['bufferView']}, which holds {len(data)}")
        out = np.ndarray((count, width), dtype=dtype, buffer=data, offset=offset,
                         strides=(stride, dtype.itemsize))
        if acc.get("normalized") and ctype != 5126:
            out = np.maximum(out / float(np.iinfo(dtype).max), -1.0)
        return np.array(out)

    def view_bytes(self, view: dict, index) -> bytes:
        where = f"buffer view {index}"
        buffer = _get(view, "buffer", int, where)
        data = self.buffer(buffer)
        start = _get(view, "byteOffset", int, where, default=0)
        length = _get(view, "byteLength", int, where)
        if start < 0 or length < 0 or start + length > len(data):
            raise _Bad(f"truncated: {where} spans bytes {start}..{start + length} of buffer "
                       f"{buffer}, which holds {len(data)}")
        return data[start:start + length]

    def buffer(self, index: int) -> bytes:
        if index in self.buffers:
            return self.buffers[index]
        spec = _item(self.doc, "buffers", index, f"buffer {index}")
        uri = spec.get("uri")
        if uri is None:
            if index != 0 or self.binary is None:
                raise _Bad(f"buffer {index} has no data (no 'uri' and no GLB binary chunk)")
            data = self.binary
        elif not isinstance(uri, str):
            raise _Bad(f"buffer {index}: 'uri' is not a string")
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1], validate=True)
            except (IndexError, ValueError):
                raise _Bad(f"buffer {index}: its data URI is not base64") from None
        else:
            data = self._external(uri, index)
        length = _get(spec, "byteLength", int, f"buffer {index}")
        if len(data) < length:
            raise _Bad(f"truncated: buffer {index} should hold {length} bytes, it has {len(data)}")
        self.buffers[index] = data
        return data

    def _external(self, uri: str, index: int) -> bytes:
        from urllib.parse import unquote

        if self.folder is None or "://" in uri:
            raise _Bad(f"buffer {index} is an external file ({uri!r}) this reader cannot reach")
        path = self.folder / unquote(uri)
        try:
            return path.read_bytes()
        except OSError as exc:
            raise _Bad(f"buffer {index}: cannot read {path} ({exc.strerror or 'unreadable'})") from None


def _corner_triangles(index: np.ndarray, mode: int) -> np.ndarray:
    """[T, 3] triangles of a primitive's corner list (triangles, strip or fan)."""
    if mode == _TRIANGLES:
        return index.reshape(-1, 3)
    n = max(len(index) - 2, 0)
    i = np.arange(n)
    if mode == _FAN:
        return np.stack([np.full(n, index[0] if len(index) else 0), index[i + 1], index[i + 2]], axis=1)
    odd = i % 2 == 1           # a strip's every other triangle is flipped to keep the orientation
    a, b = np.where(odd, i + 1, i), np.where(odd, i, i + 1)
    return np.stack([index[a], index[b], index[i + 2]], axis=1)


__all__ = ["parse_gltf", "face_count", "glb_json_size"]
