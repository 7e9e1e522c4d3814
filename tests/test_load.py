"""load_mesh: every format read with the file's faces in the file's order, gzip, and the
refusals every format shares (missing, empty, not gzip, unknown extension)."""
from __future__ import annotations

import gzip

import numpy as np
import pytest
import trimesh
from helpers.meshfiles import off_text
from helpers.refusals import assert_refused, write_file

import torchakvf as ta


@pytest.mark.parametrize("ext,kw", [("off", {}), ("obj", {}), ("ply", {}),
                                    ("ply", {"encoding": "ascii"}), ("glb", {})])
def test_load_indexed_formats_keep_faces(tmp_path, ico2_shuffled, ext, kw):
    V, F = ico2_shuffled
    path = tmp_path / f"mesh.{ext}"
    trimesh.Trimesh(V, F, process=False).export(path, **kw)
    m = ta.load_mesh(path)
    assert isinstance(m, ta.Mesh)
    assert m.name == str(path)
    assert m.faces.shape == F.shape and m.vertices.shape == V.shape
    np.testing.assert_array_equal(m.faces, F)           # same order and count
    np.testing.assert_allclose(m.vertices, V, rtol=0, atol=1e-6)


def test_load_stl_soup_keeps_face_order(tmp_path, ico2_shuffled):
    V, F = ico2_shuffled
    path = tmp_path / "mesh.stl"
    trimesh.Trimesh(V, F, process=False).export(path)
    m = ta.load_mesh(path)
    assert m.faces.shape == F.shape
    # one vertex per corner, but every triangle is the same one, in file order
    np.testing.assert_allclose(m.vertices[m.faces], V[F], atol=1e-6)
    c = ta.clean_mesh(m)
    assert c.report["merged_vertices"] == m.n_vertices - len(V)
    assert len(c.vertices) == len(V)
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))


def test_load_hand_written_off_and_gzip(tmp_path, ico2_shuffled):
    V, F = ico2_shuffled
    for inline in (False, True):
        p = write_file(tmp_path / f"h{int(inline)}.off", off_text(V, F, inline))
        m = ta.load_mesh(p)
        np.testing.assert_array_equal(m.faces, F)
        np.testing.assert_array_equal(m.vertices, V)     # repr round-trips exactly
    gz = tmp_path / "h.off.gz"
    gz.write_bytes(gzip.compress(off_text(V, F).encode()))
    m = ta.load_mesh(gz)
    assert m.name == str(gz)
    np.testing.assert_array_equal(m.faces, F)
    np.testing.assert_array_equal(m.vertices, V)
    # a gzipped OBJ goes through the other reader
    obj = tmp_path / "h.obj"
    trimesh.Trimesh(V, F, process=False).export(obj)
    (tmp_path / "h.obj.gz").write_bytes(gzip.compress(obj.read_bytes()))
    np.testing.assert_array_equal(ta.load_mesh(tmp_path / "h.obj.gz").faces, F)


def test_load_ascii_stl_keeps_face_order(tmp_path, ico2_shuffled):
    V, F = ico2_shuffled
    path = tmp_path / "mesh.stl"
    trimesh.Trimesh(V, F, process=False).export(path, file_type="stl_ascii")
    m = ta.load_mesh(path)
    assert m.faces.shape == F.shape
    np.testing.assert_allclose(m.vertices[m.faces], V[F], atol=1e-6)


BAD_FILES = {
    # name: (file name, content or None for "do not create", problem regex)
    "missing": ("absent.off", None, r"not found"),
    "empty": ("empty.off", "", r"empty"),
    "empty_obj": ("empty.obj", "   \n", r"empty"),
    "bad_gzip": ("bad.off.gz", b"this is not gzip data", r"gzip"),
    "unknown_ext": ("mesh.xyz", "0 0 0\n", r"unknown mesh format '\.xyz'"),
    "folder": ("folder.ply", None, r"directory"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_files_raise_mesh_error(tmp_path, case):
    fname, content, problem = BAD_FILES[case]
    path = tmp_path / fname
    if case == "folder":
        path.mkdir()
    elif content is not None:
        write_file(path, content)
    assert_refused(path, problem)


def test_every_format_is_listed_and_named():
    assert set(ta.io.FORMATS) == {"off", "obj", "ply", "stl", "glb", "gltf"}
    assert ta.io.mesh_format("a/b.PLY.gz") == ("ply", True)
    assert ta.io.mesh_format("scene.glb") == ("glb", False)
