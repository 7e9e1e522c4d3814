"""torchakvf.pipeline.execute: one batch loaded, computed and written; a bad input fails alone, a
bug ends the run, a failing batch is bisected."""
from __future__ import annotations

import pytest
from helpers.faketask import FakeTask
from helpers.meshfiles import write_off
from helpers.runs import by_stem, cli_run, small_meshes

from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.io.manifest import read_manifest_records
from torchakvf.pipeline.runner import run_corpus


def test_programming_error_surfaces_after_the_manifest_is_flushed(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a", "bug", "c"))
    out = tmp_path / "out"
    task = FakeTask(fail={"bug": TypeError("unsupported operand")})
    with pytest.raises(TypeError, match="unsupported operand"):
        run_corpus(paths, out, task, batch_faces=80, progress=False)
    assert [r["stem"] for r in read_manifest_records(out)] == ["a"]    # batch 1 recorded
    assert task.batches == [["a"], ["bug"]]                            # stopped there, no retry


@pytest.mark.parametrize("exc", [TorchAKVFError("bad mesh"), MemoryError(), OSError(5, "I/O error"),
                                 RuntimeError("not positive definite")])
def test_bad_input_fails_alone_and_the_run_goes_on(tmp_path, exc):
    paths = small_meshes(tmp_path / "in", names=("a", "bad", "c"))
    summary = run_corpus(paths, tmp_path / "out", FakeTask(fail={"bad": exc}), batch_faces=10_000,
                         progress=False)
    assert (summary.ok, summary.failed, summary.exit_code) == (2, 1, 1)
    assert by_stem(tmp_path / "out")["bad"]["status"] == "failed"


def test_manifest_fields_hook_and_exit_codes(tmp_path, capsys):
    paths = small_meshes(tmp_path / "in", names=("a",))
    run_corpus(paths, tmp_path / "out", FakeTask(), progress=False)
    assert by_stem(tmp_path / "out")["a"]["faces_seen"] == 80
    (tmp_path / "in" / "junk.off").write_bytes(b"OFF\n3 1 0\n")
    for cmd in (["features", "--n", "4"], ["segment", "-k", "2", "--n-fields", "4", "--formats", "seg"]):
        rc, stdout, _ = cli_run([cmd[0], tmp_path / "in", "--out", tmp_path / cmd[0], *cmd[1:]], capsys)
        assert rc == 1 and "1 ok, 1 failed" in stdout and "junk.off" in stdout
        rc, stdout, _ = cli_run([cmd[0], paths[0], "--out", tmp_path / f"{cmd[0]}-ok", *cmd[1:]], capsys)
        assert rc == 0 and "1 ok, 0 failed" in stdout


def test_batch_failure_is_bisected(tmp_path):
    ico = shapes.icosphere(1)
    names = ("a", "b", "c", "d", "e", "f", "g", "poison")
    paths = [write_off(tmp_path / "in" / f"{n}.off", ico.vertices, ico.faces) for n in names]
    task = FakeTask()
    summary = run_corpus(paths, tmp_path / "out", task, batch_faces=10_000)
    assert (summary.ok, summary.failed) == (7, 1)
    # 8 -> 4 + 4 -> (2 + 2) -> 1 + 1: the culprit ends alone, the others are never run alone
    assert task.batches == [list(names), list(names[:4]), list(names[4:]), ["e", "f"], ["g", "poison"],
                            ["g"], ["poison"]]
    runs = {n: sum(n in b for b in task.batches) for n in names}
    assert runs == {"a": 2, "b": 2, "c": 2, "d": 2, "e": 3, "f": 3, "g": 4, "poison": 4}
    recs = by_stem(tmp_path / "out")
    assert recs["poison"]["status"] == "failed" and "poisoned batch" in recs["poison"]["error"]
    assert all(recs[n]["status"] == "ok" for n in names[:-1])
    # stage time is shared by face count: equal meshes in the batch of 4 that ran get a quarter
    assert recs["a"]["seconds"]["akvf"] == pytest.approx(0.25)
