"""torchakvf.pipeline.runner: corpus runs end to end (the features task), failures, interrupt +
resume, the manifest."""
from __future__ import annotations

import gzip
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers.faketask import FakeTask
from helpers.meshfiles import write_off, write_small_corpus
from helpers.runs import by_stem

import torchakvf as ta
from torchakvf import cli, shapes
from torchakvf.io.manifest import MANIFEST, ManifestWriter, read_manifest
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.pipeline.inputs import discover_inputs
from torchakvf.pipeline.resume import prepare
from torchakvf.pipeline.runner import run_corpus

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

REPO = Path(__file__).resolve().parents[1]
N = 8
BUDGET = 600  # faces per batch: three batches for the corpus below


ENV = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """3 small meshes (one with a degenerate face in the middle, one in a subfolder) + garbage."""
    root = write_small_corpus(tmp_path_factory.mktemp("corpus"), degenerate_face=True)
    (root / "notes.txt").write_text("not a mesh")
    return root


@pytest.fixture(scope="module")
def reference(corpus, tmp_path_factory) -> Path:
    """An uninterrupted ``torchakvf features`` run over the corpus (through the CLI)."""
    out = tmp_path_factory.mktemp("ref")
    rc = cli.main(["features", str(corpus), "--out", str(out), "--n", str(N),
                   "--batch-faces", str(BUDGET)])
    assert rc == 1  # the broken file failed, the others did not
    return out


def assert_same_outputs(a: Path, b: Path, stems, exact=True) -> None:
    for stem in stems:
        za, zb = np.load(a / f"{stem}.npz", allow_pickle=False), np.load(b / f"{stem}.npz", allow_pickle=False)
        assert sorted(za.files) == sorted(zb.files)
        for key in za.files:
            if exact or za[key].dtype.kind not in "fc":
                np.testing.assert_array_equal(za[key], zb[key], err_msg=f"{stem}:{key}")
            else:
                np.testing.assert_allclose(za[key], zb[key], rtol=1e-5, atol=1e-6, err_msg=f"{stem}:{key}")


# ---- features end to end ------------------------------------------------------------------


def test_broken_file_fails_alone(reference):
    recs = by_stem(reference)
    assert recs["broken"]["status"] == "failed"
    assert "broken.off" in recs["broken"]["error"] and "OFF" in recs["broken"]["error"]
    assert not (reference / "broken.npz").exists()
    assert sum(r["status"] == "ok" for r in recs.values()) == 3
    assert not (reference / "notes.npz").exists()     # folders are scanned for mesh files only
    assert not list(reference.glob(".*.tmp"))          # no temp files left


# ---- interrupt, kill, resume, skip --------------------------------------------------------

def test_interrupt_then_resume_equals_uninterrupted(corpus, reference, tmp_path):
    out = tmp_path / "feats"
    paths = discover_inputs([str(corpus)])
    task = FeaturesTask(N)
    seen = []

    def stop_after_first(bno, records):
        seen.append(bno)
        if bno == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_corpus(paths, out, task, batch_faces=BUDGET, on_batch=stop_after_first)
    first = read_manifest(out)
    assert seen == [1] and 1 <= sum(r["status"] == "ok" for r in first.values()) < 3
    done = [r["stem"] for r in first.values() if r["status"] == "ok"]

    summary = run_corpus(paths, out, FeaturesTask(N), batch_faces=BUDGET)
    assert summary.skipped == len(done) and summary.ok == 3 - len(done) and summary.failed == 1
    assert summary.exit_code == 1
    assert_same_outputs(out, reference, ["ico", "ell", "dumb"], exact=True)

    # A third run recomputes nothing: everything ok is skipped, files untouched.
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}
    again = run_corpus(paths, out, FeaturesTask(N), batch_faces=BUDGET)
    assert (again.skipped, again.ok, again.failed) == (3, 0, 1)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == mtimes

    # Other parameters are not "done": they are recomputed.
    todo, skipped = prepare(paths, out, FeaturesTask(N + 1))
    assert len(skipped) == 0 and len(todo) == 4
    # A deleted output is redone even though its manifest line says ok.
    (out / "ico.npz").unlink()
    todo, skipped = prepare(paths, out, FeaturesTask(N))
    assert {it.stem for it in todo} == {"ico", "broken"}


KILL_SCRIPT = """
import sys, time
from pathlib import Path
from torchakvf.pipeline.runner import discover_inputs, run_corpus
from torchakvf.pipeline.features import FeaturesTask

def hook(bno, records):
    if bno == 1:
        Path(sys.argv[3]).write_text("first batch recorded")
        time.sleep(120)            # killed here, with batches 2 and 3 still to do

try:
    run_corpus(discover_inputs([sys.argv[1]]), sys.argv[2], FeaturesTask(int(sys.argv[4])),
               batch_faces=int(sys.argv[5]), on_batch=hook)
except KeyboardInterrupt:
    sys.exit(130)
"""


@pytest.mark.parametrize("sig, code", [(signal.SIGKILL, -signal.SIGKILL), (signal.SIGTERM, 130)])
def test_killed_process_then_resume(corpus, reference, tmp_path, sig, code):
    """A real process killed after its first batch (SIGKILL: no cleanup at all; SIGTERM: turned
    into KeyboardInterrupt), then resumed through the CLI: same outputs as the uninterrupted run."""
    out, flag = tmp_path / "killed", tmp_path / "flag"
    proc = subprocess.Popen([sys.executable, "-c", KILL_SCRIPT, str(corpus), str(out), str(flag),
                             str(N), str(BUDGET)], cwd=REPO, env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 120
        while not flag.exists() and proc.poll() is None and time.time() < deadline:
            time.sleep(0.05)
        assert flag.exists(), proc.stderr.read().decode()[-2000:]
        proc.send_signal(sig)
        assert proc.wait(timeout=60) == code
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    first = read_manifest(out)
    n_done = sum(r["status"] == "ok" for r in first.values())
    assert 1 <= n_done < 3
    assert not list(out.glob(".*.tmp"))
    rc = cli.main(["features", str(corpus), "--out", str(out), "--n", str(N), "--batch-faces", str(BUDGET)])
    assert rc == 1
    recs = by_stem(out)
    assert {s for s, r in recs.items() if r["status"] == "ok"} == {"ico", "ell", "dumb"}
    assert_same_outputs(out, reference, ["ico", "ell", "dumb"], exact=True)
    for stem in ("ico", "ell", "dumb"):
        with zipfile.ZipFile(out / f"{stem}.npz") as zf:
            assert zf.testzip() is None


# ---- runner logic with a fake task (no solver) --------------------------------------------


def test_peek_face_count(tmp_path):
    (tmp_path / "a.off").write_text("# c\nOFF 4 2 0\n")
    (tmp_path / "b.off").write_text("OFF\n\n# comment\n 4  7 0\n")
    with gzip.open(tmp_path / "c.off.gz", "wt") as fh:
        fh.write("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "d.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nelement face 5\nend_header\n")
    (tmp_path / "e.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n")
    (tmp_path / "f.stl").write_bytes(b"\0" * 80 + (3).to_bytes(4, "little") + b"\0" * 150)   # binary
    (tmp_path / "g.off.gz").write_bytes(gzip.compress(b"OFF 5 9 0\n"))
    got = {p.name: ta.io.peek_face_count(p) for p in sorted(tmp_path.iterdir())}
    assert got == {"a.off": 2, "b.off": 7, "c.off.gz": 1, "d.ply": 5, "e.obj": 2, "f.stl": 3, "g.off.gz": 9}
    # An unparsable header is an error naming the file, never a guess ("1 face").
    for name, data, problem in [("bad.off", b"\xff\x00", "not a text OFF"),
                                ("noff.off", b"4 2 0\n", "missing the 'OFF' header"),
                                ("counts.off", b"OFF\nfour two zero\n", "bad counts line"),
                                ("short.off", b"OFF\n", "missing the 'n_vertices"),
                                ("bin.off", b"OFF\n\xff\xfe 3\n", "not a text OFF"),
                                ("nofaces.ply", b"ply\nformat ascii 1.0\nend_header\n", "element face")]:
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ta.errors.MeshError, match=problem) as info:
            ta.io.peek_face_count(tmp_path / name)
        assert str(tmp_path / name) in str(info.value)
    with pytest.raises(ta.errors.MeshError, match="file not found"):
        ta.io.peek_face_count(tmp_path / "missing.off")


def test_torn_manifest_line_is_ignored(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST).write_bytes(b'{"path": "/a.off", "stem": "a", "status": "ok"}\n{"path": "/b.o')
    assert list(read_manifest(out)) == ["/a.off"]
    w = ManifestWriter(out)
    w.append({"path": "/c.off", "stem": "c", "status": "ok"})
    w.close()
    assert list(read_manifest(out)) == ["/a.off", "/c.off"]


# ---- Dataset ------------------------------------------------------------------------------


# ---- segment CLI --------------------------------------------------------------------------


# ---- Ray (optional) -----------------------------------------------------------------------


def test_features_npz_plain_arrays_in_input_face_order(corpus, reference):
    recs = by_stem(reference)
    assert {s for s, r in recs.items() if r["status"] == "ok"} == {"ico", "ell", "dumb"}
    for stem, src in [("ico", corpus / "ico.off"), ("ell", corpus / "ell.off"),
                      ("dumb", corpus / "sub" / "dumb.off")]:
        mesh = ta.load_mesh(src)
        with np.load(reference / f"{stem}.npz", allow_pickle=False) as z:
            f = mesh.n_faces
            assert int(z["faces_input_count"]) == f
            assert z["vertices"].shape == (mesh.n_vertices, 3) and z["vertices"].dtype == np.float32
            assert z["faces"].dtype == np.int32
            np.testing.assert_array_equal(z["faces"], mesh.faces)          # file order
            assert z["akvf_norms"].shape == (f, N) and z["features"].shape == (f, N)
            assert z["features"].dtype == np.float32
            assert z["eigenvalues"].shape == (N,) and z["eigenvalues"].dtype == np.float64
            assert z["residuals"].shape == (N,)
            assert "face_vectors" not in z.files
            params = json.loads(str(z["params_json"]))
            assert params["n"] == N and params["version"] == ta.__version__
            assert np.all(np.diff(z["eigenvalues"]) >= -1e-9)
            if stem == "ell":   # the degenerate input face 100 is kept as a zero row
                assert np.all(z["features"][100] == 0) and np.all(z["akvf_norms"][100] == 0)
                assert np.all(np.delete(z["akvf_norms"], 100, axis=0).sum(1) > 0)
        rec = recs[stem]
        assert rec["faces"] == f and rec["seed"] == 0 and rec["version"] == ta.__version__
        assert set(rec["seconds"]) == {"load", "akvf", "untangle", "write"}
        assert rec["params"]["n"] == N


def test_progress_lines_on_long_work(tmp_path, caplog, capsys, monkeypatch):
    from torchakvf.pipeline import runner

    s = shapes.icosphere(1)
    paths = [write_off(tmp_path / "in" / f"{n}.off", s.vertices, s.faces) for n in ("a", "b")]
    monkeypatch.setattr(runner, "ANNOUNCE_FACES", 50)             # "big" batches: 80 faces
    with caplog.at_level("INFO", logger="torchakvf.progress"):
        run_corpus(paths, tmp_path / "out", FakeTask(), batch_faces=80)
    err = capsys.readouterr().err
    assert "batch 1/2: 1 mesh(es), 80 faces" in err and "this can take minutes" in err
    lines = [r.getMessage() for r in caplog.records if r.name == "torchakvf.progress"]
    assert any("160/160 faces" in line for line in lines), lines


# ---- a task's own planner and resume; batches side by side ---------------------------------

class _PlannedTask(FakeTask):
    """Each mesh a batch of its own, largest first; ``done_already``: any stem in ``done``."""

    def __init__(self, done=()):
        super().__init__()
        self.done, self.asked = set(done), []

    def plan_batches(self, items, batch_faces, *, device="cpu", workers=None):
        return [[it] for it in sorted(items, key=lambda it: -it.cost)]

    def done_already(self, item):
        self.asked.append(item.stem)
        return item.stem in self.done


def test_a_task_plans_its_batches_and_says_what_is_done(corpus, tmp_path):
    task = _PlannedTask(done={"ell"})
    summary = run_corpus(discover_inputs([corpus]), tmp_path / "out", task, batch_faces=10 ** 6,
                         progress=False)
    assert sorted(task.asked) == ["broken", "dumb", "ell", "ico"]       # every input is asked
    assert summary.skipped == 1 and not (tmp_path / "out" / "ell.txt").exists()
    # the planner's batches, in its order (dumb 492 faces, ico 320), not one batch of the budget
    assert task.batches == [["dumb"], ["ico"]]
    # the hook, not the manifest, decides: a done mesh is skipped even with no manifest line
    again = _PlannedTask(done={"ell", "ico", "dumb"})
    assert run_corpus(discover_inputs([corpus]), tmp_path / "out", again, progress=False).skipped == 3


def test_batches_side_by_side_give_the_in_turn_files(corpus, tmp_path):
    """workers=2 on the in-turn path: the batches run in two processes; same files and records,
    the broken mesh failing alone."""
    runs = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        s = run_corpus(discover_inputs([corpus]), out, FakeTask(), batch_faces=BUDGET, progress=False,
                       workers=workers)
        assert (s.ok, s.failed) == (3, 1)
        runs[workers] = out
    for stem in ("ico", "ell", "dumb"):
        assert (runs[1] / f"{stem}.txt").read_bytes() == (runs[2] / f"{stem}.txt").read_bytes()
    keep = ("status", "faces_seen", "outputs")
    one, two = by_stem(runs[1]), by_stem(runs[2])
    assert {s: {k: r.get(k) for k in keep} for s, r in one.items()} == \
        {s: {k: r.get(k) for k in keep} for s, r in two.items()}
