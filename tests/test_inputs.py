"""Which files a corpus run reads: every other file a folder or pattern holds is reported with
the reason it is skipped; glTF files are read."""
from __future__ import annotations

import logging

import pytest

from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline.inputs import SkippedFile, discover_inputs, scan_inputs

from meshfiles import write_off


@pytest.fixture()
def folder(tmp_path):
    from torchakvf import shapes
    s = shapes.icosphere(1)
    write_off(tmp_path / "a.off", s.vertices, s.faces)
    (tmp_path / "scene.glb").write_bytes(b"glTF")
    (tmp_path / "model.gltf").write_text("{}")
    (tmp_path / "model.bin").write_bytes(b"\0")
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.PLY.gz").write_bytes(b"")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.seg").write_text("0\n")
    (tmp_path / "out" / "a.glb").write_bytes(b"glTF")
    return tmp_path


def test_every_skipped_file_is_named_with_its_reason(folder):
    paths, skipped = scan_inputs([str(folder)], exclude=folder / "out")
    assert [p.relative_to(folder).as_posix() for p in paths] == ["a.off", "model.gltf", "scene.glb", "sub/b.PLY.gz"]
    reasons = {s.path.relative_to(folder).as_posix(): s.reason for s in skipped}
    assert set(reasons) == {"model.bin", "notes.txt", "out/a.seg", "out/a.glb"}
    assert reasons["out/a.glb"] == "inside the output folder"
    assert reasons["notes.txt"].startswith("not a mesh file name (meshes are .off, .obj, .ply, .stl, .glb, .gltf")


def test_discover_inputs_reports_skips_by_default_and_on_request(folder, caplog):
    with caplog.at_level(logging.INFO, logger="torchakvf.pipeline"):
        paths = discover_inputs([str(folder)], exclude=folder / "out")
    assert len(paths) == 4
    text = caplog.text
    assert f"skipped {folder / 'notes.txt'}: not a mesh file name" in text
    assert f"skipped {folder / 'model.bin'}" in text
    assert "skipped 2 files inside the output folder" in text
    got: list[SkippedFile] = []
    assert discover_inputs([str(folder / "*")], exclude=folder / "out", on_skipped=got.extend) == paths[:3]
    assert sorted(s.path.name for s in got) == ["model.bin", "notes.txt"]


def test_a_folder_without_meshes_is_an_error(tmp_path):
    (tmp_path / "readme.md").write_text("x")
    with pytest.raises(TorchAKVFError, match=r"folder holds no mesh files \(\.off, .*\.glb, \.gltf"):
        discover_inputs([str(tmp_path)])
