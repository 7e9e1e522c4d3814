"""torchakvf.pipeline.inputs: which files a corpus run reads and the output stem of each."""
from __future__ import annotations

from pathlib import Path

import pytest

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline.inputs import assign_stems, discover_inputs
from torchakvf.pipeline.runner import run_corpus
from faketask import FakeTask
from meshfiles import write_off, write_small_corpus


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
