"""The corpus runner: features/segment end to end, failures, interrupt + resume, the Dataset."""
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
import torch

import torchakvf as ta
from torchakvf import cli, shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.io.manifest import MANIFEST, ManifestWriter, read_manifest
from torchakvf.pipeline.inputs import assign_stems, discover_inputs
from torchakvf.pipeline.resume import prepare
from torchakvf.pipeline.runner import run_corpus
from faketask import FakeTask, assert_one_line_error
from meshfiles import write_off, write_small_corpus
from threads import one_torch_thread  # noqa: F401 - autouse fixture

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


def run_cli(argv, capsys):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def reference(corpus, tmp_path_factory) -> Path:
    """An uninterrupted ``torchakvf features`` run over the corpus (through the CLI)."""
    out = tmp_path_factory.mktemp("ref")
    rc = cli.main(["features", str(corpus), "--out", str(out), "--n", str(N),
                   "--batch-faces", str(BUDGET)])
    assert rc == 1  # the broken file failed, the others did not
    return out


def manifest_by_stem(out: Path) -> dict:
    return {r["stem"]: r for r in read_manifest(out).values()}


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

def test_features_npz_plain_arrays_in_input_face_order(corpus, reference):
    recs = manifest_by_stem(reference)
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


def test_broken_file_fails_alone(reference):
    recs = manifest_by_stem(reference)
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
    recs = manifest_by_stem(out)
    assert {s for s, r in recs.items() if r["status"] == "ok"} == {"ico", "ell", "dumb"}
    assert_same_outputs(out, reference, ["ico", "ell", "dumb"], exact=True)
    for stem in ("ico", "ell", "dumb"):
        with zipfile.ZipFile(out / f"{stem}.npz") as zf:
            assert zf.testzip() is None


def test_cache_makes_reruns_free(tmp_path):
    s = shapes.icosphere(1)
    src = write_off(tmp_path / "in" / "a.off", s.vertices, s.faces)
    cache = tmp_path / "cache"
    first = run_corpus([src], tmp_path / "o1", FeaturesTask(N, cache_dir=cache, face_vectors=True))
    assert first.ok == 1 and first.cached == 0 and len(list(cache.glob("*.npz"))) == 1
    with np.load(tmp_path / "o1" / "a.npz", allow_pickle=False) as z:   # --face-vectors
        assert z["face_vectors"].shape == (len(s.faces), N, 3) and z["face_vectors"].dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(z["face_vectors"], axis=-1), z["features"], rtol=1e-4, atol=1e-5)
    assert ta.data.FeatureDataset(tmp_path / "o1")[0]["face_vectors"].shape == (len(s.faces), N, 3)
    # Other parameters are another cache entry: not a hit.
    other = run_corpus([src], tmp_path / "o3", FeaturesTask(N, cache_dir=cache))
    assert other.cached == 0 and len(list(cache.glob("*.npz"))) == 2
    second = run_corpus([src], tmp_path / "o2", FeaturesTask(N, cache_dir=cache, face_vectors=True))
    assert second.ok == 1 and second.cached == 1
    assert (tmp_path / "o1" / "a.npz").read_bytes() == (tmp_path / "o2" / "a.npz").read_bytes()
    rec = manifest_by_stem(tmp_path / "o2")["a"]
    assert rec["cached"] is True and rec["status"] == "ok"


# ---- runner logic with a fake task (no solver) --------------------------------------------

def test_batch_failure_is_retried_one_by_one(tmp_path):
    ico = shapes.icosphere(1)
    paths = [write_off(tmp_path / "in" / f"{n}.off", ico.vertices, ico.faces) for n in ("a", "b", "poison")]
    task = FakeTask()
    summary = run_corpus(paths, tmp_path / "out", task, batch_faces=10_000)
    assert (summary.ok, summary.failed) == (2, 1)
    assert task.batches[0] == ["a", "b", "poison"] and sorted(task.batches[1:]) == [["a"], ["b"], ["poison"]]
    recs = manifest_by_stem(tmp_path / "out")
    assert recs["poison"]["status"] == "failed" and "poisoned batch" in recs["poison"]["error"]
    # stage time is shared by face count: equal meshes in a batch of 1 get the whole second
    assert recs["a"]["seconds"]["akvf"] == pytest.approx(1.0)


def test_batches_sorted_by_size_under_face_budget(tmp_path):
    sizes = {"s1": 1, "s2": 2, "s3": 3}   # icosphere levels: 80, 320, 1280 faces
    paths = []
    for name, lvl in sizes.items():
        s = shapes.icosphere(lvl)
        paths.append(write_off(tmp_path / "in" / f"{name}.off", s.vertices, s.faces))
    task = FakeTask()
    run_corpus(list(reversed(paths)), tmp_path / "out", task, batch_faces=500)
    assert task.batches == [["s1", "s2"], ["s3"]]      # the 1280-face mesh alone, over budget


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
    for name, data, problem in [("bad.off", b"\xff\x00", "not a text OFF"), ("noff.off", b"4 2 0\n", "missing the 'OFF' header"),
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

def test_feature_dataset_round_trip(reference):
    ds = ta.data.FeatureDataset(reference)
    assert len(ds) == 3 and [f.stem for f in ds.files] == ["dumb", "ell", "ico"]
    items = [ds[i] for i in range(len(ds))]
    for it in items:
        with np.load(reference / f"{it['name']}.npz", allow_pickle=False) as z:
            for key in ("vertices", "features", "akvf_norms", "eigenvalues", "residuals"):
                np.testing.assert_array_equal(it[key].numpy(), z[key])
            np.testing.assert_array_equal(it["faces"].numpy(), z["faces"])
        assert it["faces"].dtype == torch.int64 and it["params"]["n"] == N
    batch = ta.data.collate_packed(items)
    nv = [len(it["vertices"]) for it in items]
    nf = [len(it["faces"]) for it in items]
    assert batch["vert_ptr"].tolist() == np.concatenate([[0], np.cumsum(nv)]).tolist()
    assert batch["face_ptr"].tolist() == np.concatenate([[0], np.cumsum(nf)]).tolist()
    assert batch["vertices"].shape == (sum(nv), 3) and batch["features"].shape == (sum(nf), N)
    assert batch["eigenvalues"].shape == (3, N) and batch["names"] == ["dumb", "ell", "ico"]
    for b, it in enumerate(items):
        f0, f1 = batch["face_ptr"][b], batch["face_ptr"][b + 1]
        v0 = batch["vert_ptr"][b]
        assert torch.equal(batch["faces"][f0:f1] - v0, it["faces"])
        assert torch.equal(batch["features"][f0:f1], it["features"])
        assert torch.equal(batch["vertices"][batch["faces"][f0:f1]], it["vertices"][it["faces"]])
        assert (batch["face_to_mesh"][f0:f1] == b).all()
    loader = torch.utils.data.DataLoader(ds, batch_size=2, collate_fn=ta.data.collate_packed)
    assert [len(b["names"]) for b in loader] == [2, 1]


def test_feature_dataset_without_manifest(reference, tmp_path):
    for stem in ("ico", "ell"):
        (tmp_path / f"{stem}.npz").write_bytes((reference / f"{stem}.npz").read_bytes())
    ds = ta.data.FeatureDataset(tmp_path)
    assert [it["name"] for it in ds] == ["ell", "ico"]


# ---- segment CLI --------------------------------------------------------------------------

def test_segment_end_to_end(tmp_path, capsys):
    s = shapes.dumbbell(n_around=18)
    src = write_off(tmp_path / "in" / "dumb.off", s.vertices, s.faces)
    out = tmp_path / "segs"
    rc, stdout, err = run_cli(["segment", str(src), "-k", "2", "--out", str(out), "--n-fields", "8",
                               "--formats", "seg,npz,ply"], capsys)
    assert rc == 0, err
    assert "1 ok, 0 failed" in stdout
    labels = np.loadtxt(out / "dumb.seg", dtype=int)
    assert labels.shape == (len(s.faces),) and set(labels.tolist()) == {0, 1}
    # The two ends of the dumbbell, up to the label permutation (a constant labelling scores 0.5).
    from torchakvf.evaluate.metrics import matched_agreement
    assert matched_agreement(labels, s.part_labels) >= 0.95
    assert (out / "dumb.ply").exists() and not (out / "dumb.png").exists()
    rec = manifest_by_stem(out)["dumb"]
    assert rec["status"] == "ok" and set(rec["seconds"]) == {"load", "akvf", "untangle", "cluster", "write"}
    assert rec["params"]["solver"] == "auto" and rec["params"]["method"] == "merge"   # the defaults
    rc, stdout, _ = run_cli(["segment", str(src), "-k", "2", "--out", str(out), "--n-fields", "8",
                             "--formats", "seg,npz,ply"], capsys)
    assert rc == 0 and "1 skipped" in stdout


@pytest.mark.parametrize("argv, message", [
    (["segment", "{tmp}/nope.off", "-k", "2", "--out", "{tmp}/o"], "nope.off: file not found"),
    (["segment", "{src}", "-k", "0", "--out", "{tmp}/o"], "-k must be an integer >= 1"),
    (["segment", "{src}", "-k", "two", "--out", "{tmp}/o"], "-k must be an integer"),
    (["segment", "{src}", "-k", "2", "--out", "{src}/sub"], "cannot create or write the output folder"),
    (["segment", "{src}", "-k", "2", "--formats", "seg,gif", "--out", "{tmp}/o"], "unknown format 'gif'"),
    (["features", "{src}", "--n", "-3", "--out", "{tmp}/o"], "--n must be an integer >= 1"),
    (["features", "{src}", "--batch-faces", "lots", "--out", "{tmp}/o"], "--batch-faces must be an integer"),
    # issue 11: out-of-range values are argument errors, not per-mesh failures or silent nonsense
    (["segment", "{src}", "-k", "2", "--eps", "2.5", "--out", "{tmp}/o"],
     "--eps must be a number <= 2.0 (a cosine distance never exceeds 2)"),
    (["segment", "{src}", "-k", "2", "--seed", str(2**64), "--out", "{tmp}/o"], "--seed must be an integer <= "),
    (["features", "{src}", "--seed", str(2**70), "--out", "{tmp}/o"], "--seed must be an integer <= "),
    (["features", "{src}", "--cache", "{src}/sub", "--out", "{tmp}/o"], "--cache {src}/sub: cannot create"),
    (["features", "{src}", "--max-faces", "0", "--out", "{tmp}/o"], "--max-faces must be an integer >= 1"),
    (["features", "{src}", "--coarse-faces", "x", "--out", "{tmp}/o"], "--coarse-faces must be an integer"),
])
def test_cli_user_errors_are_one_line(tmp_path, capsys, argv, message):
    s = shapes.icosphere(1)
    src = write_off(tmp_path / "m.off", s.vertices, s.faces)
    argv = [a.format(tmp=tmp_path, src=src) for a in argv]
    rc, out, err = run_cli(argv, capsys)
    assert rc == 2
    assert_one_line_error(err, message.format(src=src))
    assert not (tmp_path / "o").exists()   # nothing created before the arguments are checked


def test_cli_unwritable_out_in_subprocess(tmp_path):
    """The same through a real process: one line on stderr, no traceback, exit 2."""
    s = shapes.icosphere(1)
    src = write_off(tmp_path / "m.off", s.vertices, s.faces)
    proc = subprocess.run([sys.executable, "-m", "torchakvf.cli", "segment", str(src), "-k", "2",
                           "--out", str(src / "sub")], capture_output=True, text=True, cwd=REPO,
                          env=ENV)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"torchakvf: error: --out {src / 'sub'}: cannot create or write the output folder (Not a directory)"]


def test_k_larger_than_faces_fails_that_mesh(tmp_path, capsys):
    s = shapes.icosphere(1)   # 80 faces
    src = write_off(tmp_path / "m.off", s.vertices, s.faces)
    rc, out, err = run_cli(["segment", str(src), "-k", "100", "--out", str(tmp_path / "o")], capsys)
    assert rc == 1
    assert "0 ok, 1 failed" in out and "larger than the mesh's 80 faces" in out
    rec = manifest_by_stem(tmp_path / "o")["m"]
    assert rec["status"] == "failed" and "-k 100" in rec["error"]
    assert "Traceback" not in err


# ---- Ray (optional) -----------------------------------------------------------------------

def test_ray_runner_local(tmp_path):
    ray = pytest.importorskip("ray")
    from torchakvf.pipeline.ray_runner import run_corpus_ray

    ico = shapes.icosphere(1)
    paths = [write_off(tmp_path / "in" / f"{n}.off", ico.vertices, ico.faces) for n in ("a", "b")]
    (tmp_path / "in" / "bad.off").write_bytes(b"\xff\xfe")
    paths.append(tmp_path / "in" / "bad.off")
    ray.init(num_cpus=2, include_dashboard=False, ignore_reinit_error=True)
    try:
        summary = run_corpus_ray(paths, tmp_path / "out", FakeTask(), batch_faces=100, workers=2)
    finally:
        ray.shutdown()
    assert (summary.ok, summary.failed) == (2, 1)
    assert (tmp_path / "out" / "a.txt").read_text() == "80"
    assert manifest_by_stem(tmp_path / "out")["bad"]["status"] == "failed"
