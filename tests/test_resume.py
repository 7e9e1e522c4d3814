"""torchakvf.pipeline.resume: what a re-run skips and what it computes again; the manifest under
faults (nothing stale, nothing lost, one-line errors)."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.faketask import FakeTask, assert_one_line_error
from helpers.meshfiles import write_off
from helpers.runs import by_stem, cli_run, small_meshes

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.io.manifest import MANIFEST, ManifestWriter, read_manifest, read_manifest_records
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.pipeline.runner import run_corpus
from torchakvf.pipeline.segment_task import SegmentTask

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

REPO = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))


# ---- stale results ------------------------------------------------------------------------

def test_kill_and_resume_with_changed_parameters_recomputes_the_rewritten_mesh(tmp_path, capsys):
    """Finish -k 4; a -k 5 run rewrites one mesh's files and is killed before its manifest
    line; -k 4 again must compute that mesh again, not skip it."""
    d, e = shapes.dumbbell(n_around=12), shapes.ellipsoid(level=1)
    src = tmp_path / "in"
    write_off(src / "dumb.off", d.vertices, d.faces)
    write_off(src / "ell.off", e.vertices, e.faces)
    out = tmp_path / "O"
    argv = ["segment", src, "-k", "4", "--out", out, "--n-fields", "8", "--formats", "seg"]
    rc, stdout, err = cli_run(argv, capsys)
    assert rc == 0 and "2 ok" in stdout, err
    k4 = (out / "dumb.seg").read_bytes()
    # The killed -k 5 run: its files for 'dumb' are in place, its manifest line never written.
    side = tmp_path / "k5"
    run_corpus([src / "dumb.off"], side, SegmentTask(5, n_fields=8, formats=("seg",)), progress=False)
    k5 = (side / "dumb.seg").read_bytes()
    assert len(set(np.loadtxt(side / "dumb.seg", dtype=int).tolist())) == 5 and k5 != k4
    (out / "dumb.seg").write_bytes(k5)
    rc, stdout, err = cli_run(argv, capsys)
    assert rc == 0 and "1 ok" in stdout and "1 skipped" in stdout, stdout
    # The -k 4 result again (4 parts), not the 5 parts; the manifest vouches for this file.
    # (Labels are not compared with the first run's: that one solved dumb in a batch with ell.)
    assert len(set(np.loadtxt(out / "dumb.seg", dtype=int).tolist())) == 4
    rec = by_stem(out)["dumb"]
    assert rec["params"]["k"] == 4
    assert rec["outputs"]["dumb.seg"] == ta.io.manifest.file_fingerprint(out / "dumb.seg")


def test_torn_or_deleted_output_is_computed_again(tmp_path):
    paths = small_meshes(tmp_path / "in")
    out = tmp_path / "out"
    run_corpus(paths, out, FakeTask(), progress=False)
    (out / "a.txt").write_bytes(b"8")             # torn: a prefix of "80"
    (out / "b.txt").unlink()
    again = run_corpus(paths, out, FakeTask(), progress=False)
    assert (again.ok, again.skipped) == (2, 1)
    assert (out / "a.txt").read_text() == "80" and (out / "b.txt").read_text() == "80"


def test_changed_input_content_is_computed_again(tmp_path):
    paths = small_meshes(tmp_path / "in")
    out = tmp_path / "out"
    run_corpus(paths, out, FakeTask(), progress=False)
    s = shapes.icosphere(2)
    write_off(paths[0], s.vertices, s.faces)      # same path, another mesh
    again = run_corpus(paths, out, FakeTask(), progress=False)
    assert (again.ok, again.skipped) == (1, 2)
    assert (out / "a.txt").read_text() == "320"
    assert by_stem(out)["a"]["input"] == ta.io.manifest.file_fingerprint(paths[0])


def test_corrupt_feature_file_is_not_skipped(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a",))
    out = tmp_path / "out"
    run_corpus(paths, out, FeaturesTask(4), progress=False)
    whole = (out / "a.npz").read_bytes()
    (out / "a.npz").write_bytes(whole[: len(whole) // 2])
    again = run_corpus(paths, out, FeaturesTask(4), progress=False)
    assert (again.ok, again.skipped) == (1, 0)
    assert (out / "a.npz").read_bytes() == whole


# ---- one name, two meshes -----------------------------------------------------------------

def test_same_stem_across_runs_does_not_overwrite(tmp_path):
    s1, s2 = shapes.icosphere(1), shapes.icosphere(2)
    a = write_off(tmp_path / "a" / "x.off", s1.vertices, s1.faces)
    b = write_off(tmp_path / "b" / "x.off", s2.vertices, s2.faces)
    out = tmp_path / "O"
    run_corpus([a], out, FakeTask(), progress=False)
    run_corpus([b], out, FakeTask(), progress=False)
    stems = {r["path"]: r["stem"] for r in read_manifest(out).values()}
    assert stems[str(a.resolve())] == "x" and stems[str(b.resolve())].startswith("x-")
    assert (out / "x.txt").read_text() == "80"
    assert (out / f"{stems[str(b.resolve())]}.txt").read_text() == "320"
    # Re-running either keeps each right: both skipped, nothing overwritten.
    for p in (a, b, a):
        again = run_corpus([p], out, FakeTask(), progress=False)
        assert (again.ok, again.skipped) == (0, 1)
    both = run_corpus([b, a], out, FakeTask(), progress=False)
    assert (both.ok, both.skipped) == (0, 2)
    assert (out / "x.txt").read_text() == "80"


# ---- manifest faults ----------------------------------------------------------------------

def _unwritable_manifest(out: Path, how: str) -> str:
    """A manifest.jsonl this process cannot write (as root, chmod would not stop it)."""
    out.mkdir(parents=True)
    if how == "folder":                           # cannot be read, nor opened for appending
        (out / MANIFEST).mkdir()
        return "cannot read the manifest (Is a directory)"
    (out / MANIFEST).symlink_to(out / "gone" / "manifest.jsonl")    # a dangling link
    return "cannot open the manifest for appending (No such file or directory)"


@pytest.mark.parametrize("how", ["folder", "dangling link"])
def test_unwritable_manifest_is_one_line(tmp_path, capsys, how):
    paths = small_meshes(tmp_path / "in", names=("a",))
    out = tmp_path / "out"
    problem = _unwritable_manifest(out, how)
    with pytest.raises(TorchAKVFError, match=problem.replace("(", r"\(").replace(")", r"\)")):
        run_corpus(paths, out, FakeTask(), progress=False)
    assert not (out / "a.txt").exists()           # refused before any work
    rc, _, err = cli_run(["features", paths[0], "--out", out, "--n", "4"], capsys)
    assert rc == 2
    assert_one_line_error(err, str(out / MANIFEST), problem)


def test_unwritable_manifest_in_a_real_process(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a",))
    out = tmp_path / "out"
    problem = _unwritable_manifest(out, "dangling link")
    proc = subprocess.run([sys.executable, "-m", "torchakvf.cli", "features", str(paths[0]), "--out",
                           str(out), "--n", "4"], capture_output=True, text=True, cwd=REPO, env=ENV)
    assert proc.returncode == 2
    assert_one_line_error(proc.stderr, problem)


def _enospc_after(monkeypatch, good: int, torn: bool, truncate_fails: bool = False):
    """Appends after the first ``good`` ones fail as on a full disk (half a line written when
    ``torn``; the cut-back failing too when ``truncate_fails``)."""
    calls = {"n": 0}
    real = ManifestWriter._write

    def write(self, data):
        if data != b"\n":
            calls["n"] += 1
            if calls["n"] > good:
                if torn:
                    real(self, data[: len(data) // 2])
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(self, data)

    monkeypatch.setattr(ManifestWriter, "_write", write)
    if truncate_fails:
        def no_truncate(fd, size):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        monkeypatch.setattr(ta.io.manifest.os, "ftruncate", no_truncate)


@pytest.mark.parametrize("truncate_fails", [False, True])
def test_full_disk_during_append_loses_nothing(tmp_path, monkeypatch, capsys, truncate_fails):
    paths = small_meshes(tmp_path / "in", names=("a", "b", "c"))
    out = tmp_path / "out"
    with monkeypatch.context() as m:
        _enospc_after(m, good=1, torn=True, truncate_fails=truncate_fails)
        with pytest.raises(TorchAKVFError, match="No space left on device") as info:
            run_corpus(paths, out, FakeTask(), batch_faces=80, progress=False)
    assert "\n" not in str(info.value) and "run again" in str(info.value)
    data = (out / MANIFEST).read_bytes()
    assert data.endswith(b"\n") != truncate_fails     # cut back to whole lines where it can be
    assert [r["stem"] for r in read_manifest_records(out)] == ["a"]   # the torn tail is skipped
    # The next run (disk freed) keeps 'a' and finishes the rest.
    again = run_corpus(paths, out, FakeTask(), batch_faces=80, progress=False)
    assert (again.ok, again.skipped) == (2, 1)
    assert sorted(by_stem(out)) == ["a", "b", "c"]
    # And through the CLI: one line, exit 2.
    with monkeypatch.context() as m:
        _enospc_after(m, good=0, torn=True)
        rc, _, err = cli_run(["features", paths[0], "--out", tmp_path / "o2", "--n", "4"], capsys)
    assert rc == 2
    assert_one_line_error(err, "cannot append to the manifest", "No space left on device")


def _mount_tmpfs(where: Path, size: str) -> bool:
    where.mkdir(parents=True, exist_ok=True)
    try:
        return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                              capture_output=True).returncode == 0
    except OSError:
        return False


def test_full_disk_on_a_real_tmpfs(tmp_path):
    """A small tmpfs filled up after the first batch: the next batch's output and manifest
    writes fail; the manifest keeps whole lines and the first mesh."""
    mnt = tmp_path / "mnt"
    if not _mount_tmpfs(mnt, "256k"):
        pytest.skip("cannot mount a tmpfs here (needs root and CAP_SYS_ADMIN)")
    try:
        paths = small_meshes(tmp_path / "in", names=("a", "b", "c"))
        out = mnt / "out"
        filler = mnt / "filler"

        def fill(bno, records):
            if bno == 1:
                fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
                try:
                    while os.write(fd, b"\0" * 4096):
                        pass
                except OSError:
                    pass
                finally:
                    os.close(fd)

        with pytest.raises(TorchAKVFError, match="No space left on device") as info:
            # 5 kB per record: every append needs a new page of the full disk
            run_corpus(paths, out, FakeTask(pad=5000), batch_faces=80, progress=False, on_batch=fill)
        assert "\n" not in str(info.value)
        assert (out / MANIFEST).read_bytes().endswith(b"\n")
        assert [r["stem"] for r in read_manifest_records(out)] == ["a"]
        assert (out / "a.txt").read_text() == "80"
        filler.unlink()
        again = run_corpus(paths, out, FakeTask(pad=5000), batch_faces=80, progress=False)
        assert (again.ok, again.skipped, again.failed) == (2, 1, 0)
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_torn_tail_then_next_run(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a", "b"))
    out = tmp_path / "out"
    run_corpus(paths[:1], out, FakeTask(), progress=False)
    with open(out / MANIFEST, "ab") as fh:
        fh.write(b'{"path": "/x.off", "stem": "x", "sta')     # no newline
    assert [r["stem"] for r in read_manifest_records(out)] == ["a"]
    again = run_corpus(paths, out, FakeTask(), progress=False)
    assert (again.ok, again.skipped) == (1, 1)
    assert [r["stem"] for r in read_manifest_records(out)] == ["a", "b"]
    assert ta.data.FeatureDataset  # the dataset reads manifests with the same reader (below)


# ---- a mesh too big for full resolution ---------------------------------------------------


# ---- corrupt feature files ----------------------------------------------------------------


# ---- smaller things -----------------------------------------------------------------------


def test_stale_temp_files_are_removed_at_start(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a",))
    out = tmp_path / "out"
    out.mkdir()
    stale = out / f".a.txt.k3j2{ta.io.TEMP_SUFFIX}"       # what a SIGKILL mid-write leaves
    stale.write_bytes(b"half")
    other = out / ".notes.tmp"                             # not ours: kept
    other.write_bytes(b"keep")
    run_corpus(paths, out, FakeTask(), progress=False)
    assert not stale.exists() and other.exists()


# ---- bugs are not bad meshes; exit codes --------------------------------------------------


