"""The optional Ray executor (torchakvf.pipeline.ray_runner) in Ray's local mode: the same
outputs, manifest and resume as run_corpus. Skipped where ray is not installed."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="the Ray runner is optional: pip install 'torchakvf[ray]'")

import numpy as np  # noqa: E402
from helpers.faketask import FakeTask  # noqa: E402
from helpers.meshfiles import write_off, write_small_corpus  # noqa: E402

from torchakvf import cli, shapes  # noqa: E402
from torchakvf.pipeline.features import FeaturesTask  # noqa: E402
from torchakvf.pipeline.ray_runner import run_corpus_ray  # noqa: E402
from torchakvf.pipeline.runner import MANIFEST, discover_inputs, read_manifest, run_corpus  # noqa: E402

N = 8
BUDGET = 600  # faces per batch: each of the three meshes is a batch of its own

# One intra-op thread, as the workers run (1 CPU each): the same arithmetic, and no thrashing.
pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def ray_local():
    """A local Ray instance with 2 CPUs (two workers), shut down after this module."""
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    ray.data.DataContext.get_current().enable_progress_bars = False
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """3 meshes of 320-492 faces (one in a subfolder) and one broken file."""
    return write_small_corpus(tmp_path_factory.mktemp("corpus"))


@pytest.fixture(scope="module")
def reference(corpus, tmp_path_factory) -> Path:
    """The plain run_corpus run the Ray runs must reproduce."""
    out = tmp_path_factory.mktemp("ref")
    summary = run_corpus(discover_inputs([str(corpus)]), out, FeaturesTask(N), batch_faces=BUDGET)
    assert (summary.ok, summary.failed) == (3, 1)
    return out


def manifest_lines(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / MANIFEST).read_text().splitlines()]


def assert_same_outputs(a: Path, b: Path) -> None:
    """The same files (manifest aside), with numerically equal contents."""
    names = sorted(p.name for p in a.iterdir() if p.name != MANIFEST)
    assert names == sorted(p.name for p in b.iterdir() if p.name != MANIFEST)
    for name in names:
        if not name.endswith(".npz"):
            assert (a / name).read_bytes() == (b / name).read_bytes(), name
            continue
        with np.load(a / name, allow_pickle=False) as za, np.load(b / name, allow_pickle=False) as zb:
            assert sorted(za.files) == sorted(zb.files)
            for key in za.files:
                x, y = za[key], zb[key]
                assert x.dtype == y.dtype and x.shape == y.shape, f"{name}:{key}"
                if x.dtype.kind in "fc":
                    np.testing.assert_allclose(x, y, rtol=1e-8, atol=1e-8, err_msg=f"{name}:{key}")
                else:
                    np.testing.assert_array_equal(x, y, err_msg=f"{name}:{key}")


def assert_same_segmentations(a: Path, b: Path) -> None:
    """The same files; the same eigenvalues; the same parts up to renaming on >= 99% of faces.

    All three test shapes are exactly symmetric (a sphere, a dumbbell of revolution): which of
    two equivalent splits k-means lands on can turn on the last bits of a BLAS product, which
    differ between processes (memory alignment picks the kernel), so labels are compared as
    partitions and the basis-dependent per-face features not at all.
    """
    from torchakvf.evaluate.metrics import matched_agreement

    names = sorted(p.name for p in a.iterdir() if p.name != MANIFEST)
    assert names == sorted(p.name for p in b.iterdir() if p.name != MANIFEST)
    for name in names:
        if name.endswith(".seg"):
            la, lb = np.loadtxt(a / name, dtype=int), np.loadtxt(b / name, dtype=int)
            assert la.shape == lb.shape and matched_agreement(la, lb) >= 0.99, name
        elif name.endswith(".npz"):
            with np.load(a / name, allow_pickle=False) as za, np.load(b / name, allow_pickle=False) as zb:
                assert sorted(za.files) == sorted(zb.files)
                for key in za.files:
                    assert za[key].shape == zb[key].shape and za[key].dtype == zb[key].dtype, (name, key)
                np.testing.assert_allclose(za["eigenvalues"], zb["eigenvalues"], rtol=1e-6, atol=1e-8)


def assert_same_manifest(a: Path, b: Path) -> None:
    """One line per mesh in each, with the same status, error and parameters per input."""
    la, lb = manifest_lines(a), manifest_lines(b)
    assert len(la) == len({r["path"] for r in la}) == len(lb) == len({r["path"] for r in lb})
    ra, rb = {r["path"]: r for r in la}, {r["path"]: r for r in lb}
    assert ra.keys() == rb.keys()
    for path in ra:
        x, y = ra[path], rb[path]
        assert set(x) == set(y)
        for key in ("stem", "faces", "status", "error", "seed", "version", "task", "params"):
            assert x[key] == y[key], (path, key)
        assert set(x["seconds"]) == set(y["seconds"])


def test_features_on_ray_equal_run_corpus_and_resume(ray_local, corpus, reference, tmp_path):
    paths = discover_inputs([str(corpus)])
    out = tmp_path / "ray"
    summary = run_corpus_ray(paths, out, FeaturesTask(N), batch_faces=BUDGET, workers=2)
    assert (summary.ok, summary.failed, summary.skipped) == (3, 1, 0) and summary.exit_code == 1
    assert_same_outputs(out, reference)
    assert_same_manifest(out, reference)
    recs = {r["stem"]: r for r in manifest_lines(out)}
    assert {s for s, r in recs.items() if r["status"] == "ok"} == {"ico", "ell", "dumb"}
    assert recs["broken"]["status"] == "failed" and "broken.off" in recs["broken"]["error"]
    assert summary.failures == [(recs["broken"]["path"], recs["broken"]["error"])]
    assert not (out / "broken.npz").exists() and not list(out.glob(".*.tmp"))

    # Resume: everything ok is skipped and left untouched; only the broken file is tried again.
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}
    again = run_corpus_ray(paths, out, FeaturesTask(N), batch_faces=BUDGET, workers=2)
    assert (again.skipped, again.ok, again.failed) == (3, 0, 1)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == mtimes
    lines = manifest_lines(out)
    assert len(lines) == 5 and lines[-1]["stem"] == "broken" and lines[-1]["status"] == "failed"
    # The manifest is run_corpus's: the plain runner resumes a Ray run too.
    plain = run_corpus(paths, out, FeaturesTask(N), batch_faces=BUDGET)
    assert (plain.skipped, plain.ok, plain.failed) == (3, 0, 1)
    assert {r["stem"]: r["status"] for r in read_manifest(out).values()} == {
        "ico": "ok", "ell": "ok", "dumb": "ok", "broken": "failed"}


def test_segment_cli_ray_workers_equal_plain(ray_local, corpus, tmp_path, capsys):
    argv = ["segment", str(corpus), "-k", "2", "--n-fields", "8", "--formats", "seg,npz",
            "--batch-faces", str(BUDGET)]
    assert cli.main(argv + ["--out", str(tmp_path / "plain")]) == 1
    capsys.readouterr()
    assert cli.main(argv + ["--out", str(tmp_path / "ray"), "--ray-workers", "2"]) == 1
    stdout = capsys.readouterr().out
    assert "3 ok, 1 failed, 0 skipped" in stdout and "broken.off" in stdout
    assert_same_segmentations(tmp_path / "ray", tmp_path / "plain")
    assert_same_manifest(tmp_path / "ray", tmp_path / "plain")
    labels = np.loadtxt(tmp_path / "ray" / "dumb.seg", dtype=int)
    assert labels.shape == (len(shapes.dumbbell(n_around=18).faces),)


@pytest.mark.parametrize("value, message", [("-1", "--ray-workers must be an integer >= 0"),
                                            ("two", "--ray-workers must be an integer")])
def test_ray_workers_flag_errors_are_one_line(tmp_path, capsys, value, message):
    s = shapes.icosphere(1)
    src = write_off(tmp_path / "m.off", s.vertices, s.faces)
    rc = cli.main(["features", str(src), "--out", str(tmp_path / "o"), "--ray-workers", value])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("torchakvf: error: ")
    assert message in lines[0] and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_a_bad_file_fails_alone_on_ray(ray_local, tmp_path):
    ico = shapes.icosphere(1)
    paths = [write_off(tmp_path / "in" / f"{n}.off", ico.vertices, ico.faces) for n in ("a", "b")]
    (tmp_path / "in" / "bad.off").write_bytes(b"\xff\xfe")
    paths.append(tmp_path / "in" / "bad.off")
    summary = run_corpus_ray(paths, tmp_path / "out", FakeTask(), batch_faces=100, workers=2)
    assert (summary.ok, summary.failed) == (2, 1)
    assert (tmp_path / "out" / "a.txt").read_text() == "80"
    by_stem = {r["stem"]: r for r in read_manifest(tmp_path / "out").values()}
    assert by_stem["bad"]["status"] == "failed"


def test_eval_on_ray_equal_the_plain_eval(ray_local, tmp_path):
    """``evaluate_psb(ray_workers=2)``: the evaluation task on Ray actors writes the plain run's
    prediction files (same bytes: each mesh alone, same calls) and scores; a re-run resumes."""
    from helpers.meshfiles import write_off, write_seg

    from torchakvf import shapes
    from torchakvf.evaluate.harness import evaluate_psb

    root = tmp_path / "psb"
    for i, s in enumerate((shapes.dumbbell(n_around=16), shapes.three_blobs(n_around=16)), 1):
        write_off(root / "meshes" / f"{i}.off", s.vertices, s.faces)
        write_seg(root / "gt" / str(i) / f"{i}_0.seg", s.part_labels)
    fast = dict(kmeans_restarts=2, untangle_restarts=1, n_fields=8, metrics="rand", plot=False, progress=False)
    plain = evaluate_psb(root, tmp_path / "plain", workers=1, **fast)
    on_ray = evaluate_psb(root, tmp_path / "ray", ray_workers=2, **fast)
    seg = sorted(p.relative_to(tmp_path / "plain") for p in (tmp_path / "plain" / "pred").rglob("*.seg"))
    assert len(seg) == 2
    for rel in seg:
        assert (tmp_path / "ray" / rel).read_bytes() == (tmp_path / "plain" / rel).read_bytes()
    assert [r.metrics for r in on_ray.rows] == [r.metrics for r in plain.rows]
    assert len(manifest_lines(tmp_path / "ray")) == 2
    again = evaluate_psb(root, tmp_path / "ray", ray_workers=2, **fast)
    assert [r.metrics for r in again.rows] == [r.metrics for r in plain.rows]
    assert len(manifest_lines(tmp_path / "ray")) == 2          # nothing run again


def test_gpus_per_worker_is_gone_with_a_line_saying_why(tmp_path):
    """A CUDA device reserves one GPU per actor; the removed keyword fails naming that."""
    from torchakvf.errors import TorchAKVFError
    with pytest.raises(TorchAKVFError, match="gpus_per_worker.*each actor reserves one GPU"):
        run_corpus_ray([], tmp_path / "out", FakeTask(), gpus_per_worker=1.0)
