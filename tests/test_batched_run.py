"""torchakvf.pipeline.batched_run: ``segment --batched`` through the host/device overlap gives
the files and manifest records of the in-turn batched path (the same solve of the same batch;
the cut reads its own rows only, shipped whole), fails a bad mesh alone, resumes, and writes and
prints the same per-stage timings as ``eval --batched``."""
from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.meshfiles import write_off
from helpers.runs import by_stem, cli_run

from torchakvf import shapes
from torchakvf.pipeline import runner
from torchakvf.pipeline.batched_run import TIMINGS, overlaps
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.pipeline.segment_task import SegmentTask

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

FAST = dict(n_fields=8, kmeans_restarts=2, untangle_restarts=1, formats=("seg", "npz"))
#: the stages a batched segment run records: the solving process's, then the host workers'
STAGES = {"pack", "akvf", "untangle", "cluster", "jobs", "prepare", "cut", "write", "wait_prepare",
          "wait_cut", "solve", "other", "host_share", "workers", "batches", "bisections", "run_here", "wall"}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    for name, s in (("a", shapes.dumbbell(n_around=12)), ("b", shapes.three_blobs(n_around=12)),
                    ("c", shapes.dumbbell(n_around=16))):
        write_off(root / f"{name}.off", s.vertices, s.faces)
    (root / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n")
    return sorted(root.glob("*.off"))


def _run(paths, out, workers, monkeypatch=None, **kw):
    task = SegmentTask(2, batched=True, **FAST)
    if monkeypatch is not None:         # the in-turn path: one process loads, solves, cuts, writes
        monkeypatch.setattr(runner, "overlapped", lambda task, device: False)
    return runner.run_corpus(paths, out, task, workers=workers, progress=False, **kw)


def test_overlap_gives_the_in_turn_files_and_records(corpus, tmp_path, monkeypatch):
    over = _run(corpus, tmp_path / "over", 2)
    assert (over.ok, over.failed) == (3, 1) and "truncated" in over.failures[0][1]
    with monkeypatch.context() as m:
        turn = _run(corpus, tmp_path / "turn", 1, m)
    assert turn.timings is None and not (tmp_path / "turn" / TIMINGS).exists()
    for stem in "abc":
        assert (tmp_path / "over" / f"{stem}.seg").read_bytes() == (tmp_path / "turn" / f"{stem}.seg").read_bytes()
    ro, rt = by_stem(tmp_path / "over"), by_stem(tmp_path / "turn")
    assert {s: r["status"] for s, r in ro.items()} == {s: r["status"] for s, r in rt.items()}
    for stem in "abc":
        assert ro[stem]["params"] == rt[stem]["params"] and ro[stem]["input"] == rt[stem]["input"]
        assert ro[stem]["outputs"][f"{stem}.seg"] == rt[stem]["outputs"][f"{stem}.seg"]
        assert set(ro[stem]["seconds"]) == {"load", "akvf", "untangle", "cluster", "write"}
        assert ro[stem]["converged"] == rt[stem]["converged"]
    t = json.loads((tmp_path / "over" / TIMINGS).read_text())
    assert set(t) == STAGES and t == over.timings
    assert t["workers"] == 1 and t["batches"] >= 1 and t["akvf"] > 0 and t["cut"] > 0 and 0 <= t["host_share"] <= 1


def test_resume_skips_what_the_overlap_finished(corpus, tmp_path):
    _run(corpus, tmp_path / "o", 1)
    again = _run(corpus, tmp_path / "o", 1)
    assert (again.ok, again.skipped, again.failed) == (0, 3, 1)


def test_cli_segment_batched_prints_the_stage_line(corpus, tmp_path, capsys):
    rc, stdout, err = cli_run(["segment", *corpus[:2], "--out", tmp_path / "o", "-k", "2", "--n-fields", "8",
                               "--formats", "seg", "--batched", "--workers", "1"], capsys)
    assert rc == 0 and "2 ok, 0 failed" in stdout
    assert "torchakvf segment: batched: " in err + stdout and "host share" in err + stdout
    assert json.loads((tmp_path / "o" / TIMINGS).read_text())["workers"] == 0


def test_features_overlap_gives_the_in_turn_arrays_and_uses_the_cache(corpus, tmp_path, monkeypatch):
    """features --batched through the overlap: the in-turn path's arrays; a second run into
    another folder copies every mesh from the content cache (not solved again)."""
    def run(out, workers, cache=None):
        task = FeaturesTask(8, batched=True, part_descriptors=False, cache_dir=cache)
        return runner.run_corpus(corpus, out, task, workers=workers, progress=False)

    over = run(tmp_path / "over", 2, tmp_path / "cache")
    with monkeypatch.context() as m:
        m.setattr(runner, "overlapped", lambda task, device: False)
        run(tmp_path / "turn", 1)
    assert (over.ok, over.failed) == (3, 1) and set(over.timings) >= {"akvf", "untangle", "write", "host_share"}
    for stem in "abc":
        a, b = np.load(tmp_path / "over" / f"{stem}.npz"), np.load(tmp_path / "turn" / f"{stem}.npz")
        for key in ("features", "akvf_norms", "eigenvalues", "descriptors"):
            assert np.array_equal(a[key], b[key]), (stem, key)
    again = run(tmp_path / "again", 2, tmp_path / "cache")
    assert (again.ok, again.cached, again.failed) == (3, 3, 1) and again.timings["batches"] >= 1
    assert all((tmp_path / "again" / f"{stem}.npz").read_bytes() == (tmp_path / "over" / f"{stem}.npz").read_bytes()
               for stem in "abc")


def test_which_tasks_overlap():
    assert overlaps(SegmentTask(2)) and overlaps(FeaturesTask(8))
    assert not overlaps(SegmentTask("auto", batched=True))         # k auto runs whole (process)
    assert runner.overlapped(SegmentTask(2, batched=True), "cpu")
    assert not runner.overlapped(SegmentTask(2), "cpu")            # the CPU's default: in turn
    assert not runner.overlapped(SegmentTask(2, batched=False), "cuda")
    assert runner.overlapped(FeaturesTask(8, batched=True), "cpu") and not runner.overlapped(FeaturesTask(8), "cpu")


def test_features_overlap_decimates_as_the_in_turn_path(corpus, tmp_path, monkeypatch):
    """With decimation, the overlap's host workers decimate each mesh as the descriptors' own
    batch does (canonically): the in-turn path's arrays."""
    def run(out, workers):
        task = FeaturesTask(8, batched=True, part_descriptors=False, coarse_faces=200)
        return runner.run_corpus(corpus, out, task, workers=workers, progress=False)

    over = run(tmp_path / "over", 2)
    with monkeypatch.context() as m:
        m.setattr(runner, "overlapped", lambda task, device: False)
        run(tmp_path / "turn", 1)
    assert (over.ok, over.failed) == (3, 1)
    for stem in "abc":
        a, b = np.load(tmp_path / "over" / f"{stem}.npz"), np.load(tmp_path / "turn" / f"{stem}.npz")
        for key in ("features", "akvf_norms", "eigenvalues", "descriptors"):
            assert np.array_equal(a[key], b[key]), (stem, key)
