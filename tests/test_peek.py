"""Face counts read cheaply from each format's header (or lines), as the full read counts them."""
from __future__ import annotations

import gzip

import pytest
import trimesh

import torchakvf as ta
from torchakvf import shapes


@pytest.mark.parametrize("ext,kw", [("off", {}), ("obj", {}), ("ply", {}), ("ply", {"encoding": "ascii"}),
                                    ("stl", {}), ("stl", {"file_type": "stl_ascii"}), ("glb", {})])
@pytest.mark.parametrize("gz", [False, True])
def test_peek_equals_the_faces_read(tmp_path, ext, kw, gz):
    s = shapes.icosphere(2)
    path = tmp_path / f"m.{ext}"
    trimesh.Trimesh(s.vertices, s.faces, process=False).export(path, **kw)
    if gz:
        path = path.with_name(path.name + ".gz")
        path.write_bytes(gzip.compress((tmp_path / f"m.{ext}").read_bytes()))
    assert ta.io.peek_face_count(path) == ta.load_mesh(path).n_faces == len(s.faces)


def test_peek_refuses_a_header_it_cannot_read(tmp_path):
    (tmp_path / "x.ply").write_bytes(b"not a ply")
    with pytest.raises(ta.MeshError, match=r"x\.ply: missing the 'ply' header"):
        ta.io.peek_face_count(tmp_path / "x.ply")
    with pytest.raises(ta.MeshError, match="file not found"):
        ta.io.peek_face_count(tmp_path / "absent.glb")
