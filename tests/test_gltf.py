"""The glTF/GLB reader: a scene's meshes as one mesh in world coordinates, faces in the
stated order (nodes depth first in file order, primitives, triangles), every fault refused."""
from __future__ import annotations

import base64
import json
import struct

import numpy as np
import pytest
import trimesh
from helpers.refusals import assert_refused, write_file

import torchakvf as ta
from torchakvf import shapes
from torchakvf.io.gltf import face_count, parse_gltf


def _two_mesh_scene():
    ico = shapes.icosphere(1)
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.Trimesh(ico.vertices, ico.faces, process=False), node_name="ico",
                       geom_name="ico", transform=trimesh.transformations.translation_matrix([5, 0, 0]))
    scene.add_geometry(box, node_name="box", geom_name="box",
                       transform=trimesh.transformations.scale_matrix(2.0))
    return ico, box, scene.export(file_type="glb")


def test_glb_with_two_meshes_is_one_mesh_in_world_coordinates(tmp_path):
    ico, box, data = _two_mesh_scene()
    path = write_file(tmp_path / "scene.glb", data)
    m = ta.load_mesh(path)
    n_ico = len(ico.faces)
    assert m.n_faces == n_ico + len(box.faces) == ta.io.peek_face_count(path)
    # the file's node order: the sphere's faces first, then the box's, each in its own order
    np.testing.assert_allclose(m.vertices[m.faces[:n_ico]], ico.vertices[ico.faces] + [5, 0, 0], atol=1e-6)
    np.testing.assert_allclose(m.vertices[m.faces[n_ico:]], 2 * box.vertices[box.faces], atol=1e-6)
    c = ta.clean_mesh(m)
    assert c.n_components == 2


def _gltf(positions, primitives, nodes, scenes=None, extra=None):
    """glTF JSON with one buffer (a data URI): positions [P, 3] float32, then each primitive's
    uint16 indices; primitives: (mode, indices or None)."""
    blob = np.asarray(positions, dtype="<f4").tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3"}]
    prims = []
    for mode, index in primitives:
        prim = {"attributes": {"POSITION": 0}, "mode": mode}
        if index is not None:
            raw = np.asarray(index, dtype="<u2").tobytes()
            views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw)})
            accessors.append({"bufferView": len(views) - 1, "componentType": 5123, "count": len(index),
                              "type": "SCALAR"})
            blob += raw + b"\0" * (-len(raw) % 4)
            prim["indices"] = len(accessors) - 1
        prims.append(prim)
    doc = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(blob),
           "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
           "bufferViews": views, "accessors": accessors, "meshes": [{"primitives": prims}], "nodes": nodes}
    if scenes is not None:
        doc["scenes"], doc["scene"] = scenes, 0
    doc.update(extra or {})
    return json.dumps(doc).encode()


_SQUARE = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]


def test_node_tree_depth_first_with_transforms():
    nodes = [{"children": [1], "translation": [10, 0, 0]},
             {"mesh": 0, "scale": [2, 2, 2]},
             {"mesh": 0, "rotation": [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)]}]   # 90 deg about z
    raw = _gltf(_SQUARE, [(4, [0, 1, 2, 0, 2, 3])], nodes, scenes=[{"nodes": [2, 0]}])
    v, f = parse_gltf(raw, "t.gltf")
    assert f.shape == (4, 3) and face_count(raw, "t") == 4
    np.testing.assert_allclose(v[f[0]], [[0, 0, 0], [0, 1, 0], [-1, 1, 0]], atol=1e-12)     # node 2 first
    np.testing.assert_allclose(v[f[2]], [[10, 0, 0], [12, 0, 0], [12, 2, 0]], atol=1e-12)   # node 0 -> 1


def test_strips_fans_and_non_indexed_primitives():
    points = _SQUARE + [[0, 0, 1], [1, 0, 1]]
    raw = _gltf(points, [(5, [0, 1, 3, 2]), (6, [0, 1, 2, 3]), (4, None), (1, [0, 1])], [{"mesh": 0}])
    v, f = parse_gltf(raw, "s.gltf")
    assert len(f) == 6 == face_count(raw, "s")       # 2 strip, 2 fan, 2 unindexed; no line faces
    corners = [[0, 1, 3], [3, 1, 2], [0, 1, 2], [0, 2, 3], [0, 1, 2], [3, 4, 5]]
    np.testing.assert_array_equal(f - np.repeat([0, 6, 12], 2)[:, None], corners)


def test_gltf_with_an_external_buffer(tmp_path):
    ico, box, glb = _two_mesh_scene()
    scene = trimesh.load(trimesh.util.wrap_as_stream(glb), file_type="glb")
    files = scene.export(file_type="gltf")
    for name, data in files.items():
        write_file(tmp_path / name, data)
    m = ta.load_mesh(tmp_path / "model.gltf")
    assert m.n_faces == len(ico.faces) + len(box.faces)


BAD = {
    "not_gltf": (b"hello world", r"not a glTF file"),
    "version_1": (b'{"asset": {"version": "1.0"}}', r"glTF version 1.0 is not read"),
    "draco": (b'{"asset": {"version": "2.0"}, "extensionsRequired": ["KHR_draco_mesh_compression"]}',
              r"needs extension KHR_draco_mesh_compression"),
    "no_triangles": (b'{"asset": {"version": "2.0"}, "nodes": []}', r"no triangles found"),
    "missing_mesh": (b'{"asset": {"version": "2.0"}, "nodes": [{"mesh": 3}]}',
                     r"node 0 refers to mesh 3, the file has 0 meshes"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_gltf_files_are_refused(tmp_path, case):
    content, problem = BAD[case]
    assert_refused(write_file(tmp_path / "x.gltf", content), problem)


def test_gltf_faults_in_buffers_and_indices(tmp_path):
    nodes = [{"mesh": 0}]
    raw = _gltf(_SQUARE, [(4, [0, 1, 2, 0, 2, 7])], nodes)
    assert_refused(write_file(tmp_path / "i.gltf", raw),
                   r"mesh 0 primitive 0: triangle 1 has vertex index 7 outside 0\.\.3")
    raw = _gltf(_SQUARE, [(4, [0, 1, 2, 0])], nodes)
    assert_refused(write_file(tmp_path / "c.gltf", raw), r"lists 4 corners, not a multiple of 3")
    raw = _gltf(_SQUARE, [(4, [0, 1, 2])], nodes).replace(b'"count": 4, "type": "VEC3"', b'"count": 9, "type": "VEC3"')
    assert_refused(write_file(tmp_path / "t.gltf", raw), r"truncated: accessor 0 \(mesh 0 primitive 0 POSITION\) reads")


def test_glb_container_faults(tmp_path):
    _, _, data = _two_mesh_scene()
    assert_refused(write_file(tmp_path / "cut.glb", data[:-100]),
                   rf"truncated: the GLB header says {len(data)} bytes, the file has {len(data) - 100}")
    assert_refused(write_file(tmp_path / "tiny.glb", data[:10]), r"truncated: a GLB starts with a 20-byte header")
    bad = bytearray(data)
    bad[4:8] = struct.pack("<I", 1)
    assert_refused(write_file(tmp_path / "v1.glb", bytes(bad)), r"GLB version 1 is not read")
