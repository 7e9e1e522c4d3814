"""torchakvf.pipeline.inputs: which files a corpus run reads (every other file a folder or pattern
holds is reported with the reason it is skipped; glTF files are read) and the output stem of each."""
from __future__ import annotations

import logging
from pathlib import Path

import pytest
from helpers.faketask import FakeTask
from helpers.meshfiles import write_off, write_small_corpus

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline.inputs import SkippedFile, assign_stems, discover_inputs, scan_inputs
from torchakvf.pipeline.runner import run_corpus


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """3 small meshes (one in a subfolder), a broken one and a file that is no mesh."""
    root = write_small_corpus(tmp_path_factory.mktemp("corpus"))
    (root / "notes.txt").write_text("not a mesh")
    return root


def test_stems_stay_inside_out_and_collisions_are_disambiguated(tmp_path):
    names = [Path("../../evil.off"), Path("/x/../../.hidden.off.gz"), Path("a/m.off"), Path("b/m.off"),
             Path("sp ace;rm -rf.obj"), Path("...off")]
    stems = assign_stems(names)
    assert len(set(stems)) == len(stems)
    out = (tmp_path / "out").resolve()
    for stem in stems:
        assert stem == ta.io.safe_stem(stem) and "/" not in stem and not stem.startswith(".")
        assert (out / f"{stem}.npz").resolve().parent == out
    assert stems[2].startswith("m-") and stems[3].startswith("m-")
    # an input really named with '..' components writes inside --out
    s = shapes.icosphere(1)
    deep = tmp_path / "x" / "y"
    deep.mkdir(parents=True)
    write_off(tmp_path / "evil.off", s.vertices, s.faces)
    run_corpus([deep / ".." / ".." / "evil.off"], tmp_path / "out", FakeTask())
    assert (tmp_path / "out" / "evil.txt").exists() and not (tmp_path / "evil.txt").exists()


def test_discover_inputs(tmp_path, corpus):
    found = discover_inputs([str(corpus)])
    assert sorted(p.name for p in found) == ["broken.off", "dumb.off", "ell.off", "ico.off"]
    assert [p.name for p in discover_inputs([str(corpus / "*.off")])] == ["broken.off", "ell.off", "ico.off"]
    assert len(discover_inputs([str(corpus / "**" / "*.off"), str(corpus / "ico.off")])) == 4  # dedup
    assert discover_inputs([str(corpus)], exclude=corpus / "sub") == [p for p in found if p.name != "dumb.off"]
    with pytest.raises(TorchAKVFError, match="nope.off: file not found"):
        discover_inputs([str(tmp_path / "nope.off")])
    with pytest.raises(TorchAKVFError, match="matches no mesh files"):
        discover_inputs([str(tmp_path / "*.obj")])
    with pytest.raises(TorchAKVFError, match="not a mesh file"):
        discover_inputs([str(corpus / "notes.txt")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(TorchAKVFError, match="no mesh files"):
        discover_inputs([str(tmp_path / "empty")])


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
