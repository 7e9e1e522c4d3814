"""``torchakvf bench``: one-line CLI errors, and a tiny end-to-end run on a fake PSB folder."""
from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.meshfiles import write_off, write_seg

from torchakvf import shapes
from torchakvf.bench import run as bench
from torchakvf.cli import main
from torchakvf.mesh.coarse import DEFAULT_COARSE_FACES
from torchakvf.pipeline.batches import default_batch_faces
from torchakvf.pipeline.parallel import default_workers

# Tiny meshes: intra-op threads only spin (and the test machine is shared).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

@pytest.fixture()
def fake_psb(tmp_path):
    """Mesh 1 (Human): a small dumbbell with two human segmentations (2 and 3 parts: k's 2, 3).
    Mesh 21 (Cup): three small blobs without ground truth (the harness's default k)."""
    root = tmp_path / "psb"
    d = shapes.dumbbell(n_around=12)
    write_off(root / "meshes" / "1.off.gz", d.vertices, d.faces, gz=True)
    z = d.vertices[d.faces].mean(axis=1)[:, 2]
    write_seg(root / "gt" / "1" / "1_0.seg", d.part_labels)
    write_seg(root / "gt" / "1" / "1_1.seg", np.digitize(z, [-0.5, 0.5]))
    t = shapes.three_blobs(n_around=12)
    write_off(root / "meshes" / "21.off", t.vertices, t.faces)
    return root, len(d.faces) + len(t.faces)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("torchakvf: error: ")
    return err[0]


def test_missing_psb_folder_is_one_line(tmp_path, capsys):
    assert main(["bench", "--psb", str(tmp_path / "nowhere"), "--out", str(tmp_path / "b")]) == 2
    assert "no PSB data at" in _one_error_line(capsys)
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("flag,value,words", [
    ("--limit", "0", "--limit must be an integer >= 1"),
    ("--limit", "many", "--limit must be an integer"),
    ("--baseline-every", "-1", "--baseline-every must be an integer >= 0"),
    ("--batch-faces", "0", "--batch-faces must be an integer >= 1"),
    ("--seed", "x", "--seed must be an integer"),
    ("--device", "tpu9", "--device"),
    ("--categories", "Robots", "unknown PSB category 'Robots'"),
    ("--categories", "Spring", "has no meshes"),
    ("--budgets", "4000,lots", "--budgets must be integers >= 1"),
    ("--budgets", "0", "--budgets must be integers >= 1"),
    ("--repeats", "0", "--repeats must be an integer >= 1"),
])
def test_bad_options_are_one_line(fake_psb, tmp_path, capsys, flag, value, words):
    root, _ = fake_psb
    assert main(["bench", "--psb", str(root), "--out", str(tmp_path / "b"), flag, value]) == 2
    assert words in _one_error_line(capsys)


def test_out_that_is_a_file_is_one_line(fake_psb, tmp_path, capsys):
    root, _ = fake_psb
    (tmp_path / "f").write_text("")
    assert main(["bench", "--psb", str(root), "--out", str(tmp_path / "f")]) == 2
    assert "--out" in _one_error_line(capsys)


def test_end_to_end_report(fake_psb, tmp_path, capsys):
    root, n_faces = fake_psb
    out = tmp_path / "bench"
    assert main(["bench", "--psb", str(root), "--out", str(out), "--baseline-every", "1",
                 "--seed", "0"]) == 0
    stdout = capsys.readouterr().out
    assert "torchakvf bench: 2/2 meshes" in stdout and "scipy" in stdout

    # Only the two reports remain; the scratch predictions stayed inside --out and are gone.
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "report.md"]
    r = json.loads((out / "report.json").read_text())
    assert r["selection"]["mesh_ids"] == [1, 21]
    assert r["selection"]["ks"] == {"1": [2, 3], "21": [6]}   # protocol k's; 6 = DEFAULT_K_NO_GT
    assert r["selection"]["faces"] == n_faces and r["selection"]["predictions"] == 3
    # Decimation on by default: one decimated mesh a batch on CPU, one worker process a core.
    assert r["settings"]["batch_faces"] == default_batch_faces("cpu", DEFAULT_COARSE_FACES)
    assert r["settings"]["segment_kwargs"]["coarse_faces"] == DEFAULT_COARSE_FACES
    assert r["runs"]["batched"]["workers"] == default_workers("cpu")
    assert set(r["runs"]) == {"batched", "one_at_a_time", "scipy", "batched_subset"}
    for name, run in r["runs"].items():
        assert run["meshes_ok"] == 2 and not run["failed"], (name, run["failed"])
        assert run["meshes_per_second"] > 0 and run["faces_per_second"] > 0
        assert run["faces_ok"] == n_faces
        assert set(run["stage_seconds"]) == set(bench.STAGES)
        assert run["stage_seconds"]["akvf"] > 0 and run["stage_seconds"]["segment"] > 0
        assert abs(sum(run["stage_seconds"].values()) - run["wall_seconds"]) < 1e-6 + 0.01 * run["wall_seconds"]
        assert {k: v["predictions"] for k, v in run["segment_seconds_by_k"].items()} == \
            {"2": 1, "3": 1, "6": 1}
        assert run["ru_maxrss_mib"] > 0
        if run["kind"] == "torchakvf":   # CPU time of this process and of its finished workers
            assert run["cpu_seconds"] > 0.1 * run["stage_seconds"]["akvf"], (name, run["cpu_seconds"])
    # 564 faces fit one batch at the default budget, but several workers get a batch each
    assert r["runs"]["batched"]["batches"] == min(2, r["runs"]["batched"]["workers"])
    assert r["runs"]["one_at_a_time"]["batches"] == 2 and r["runs"]["one_at_a_time"]["batch_faces"] == 1
    c = r["comparison"]
    assert c["mesh_ids"] == [1, 21] and not c["excluded"]
    for name in ("one_at_a_time", "scipy"):
        v = c["ratios"][name]
        assert v["ratio"] > 0 and v["baseline_seconds"] > 0
        assert v["torchakvf_seconds"] == r["runs"]["batched_subset"]["wall_seconds"]
        assert abs(v["ratio"] - v["baseline_seconds"] / v["torchakvf_seconds"]) < 1e-9
        assert v["stage_ratios"]["akvf"] > 0 and v["stage_ratios"]["segment"] > 0
    assert r["peak_memory"]["ru_maxrss_mib"] > 0
    assert r["peak_memory"]["total_rss_bound_mib"] >= r["peak_memory"]["ru_maxrss_mib"]
    if default_workers("cpu") > 1:
        assert r["peak_memory"]["worker_maxrss_mib"] > 0
    md = (out / "report.md").read_text()
    assert "meshes/s" in md and "one_at_a_time" in md and "scipy" in md and "## Runs" in md


def test_without_scipy_reference_and_baselines_off(fake_psb, tmp_path, monkeypatch):
    root, _ = fake_psb
    # The scipy baseline cannot be imported: it is skipped, with a note.
    monkeypatch.setattr(bench, "load_scipy_reference",
                        lambda: (None, "scipy baseline skipped: importing torchakvf.scipy_reference failed (test)"))
    fast = dict(n_fields=16, kmeans_restarts=2, untangle_restarts=1)
    r = bench.run_bench(root, tmp_path / "b1", baseline_every=2, limit=2, **fast)
    assert r["runs"]["scipy"]["skipped"].startswith("scipy baseline skipped")
    assert r["comparison"]["mesh_ids"] == [1] and r["comparison"]["ratios"]["scipy"] is None
    assert r["comparison"]["ratios"]["one_at_a_time"]["ratio"] > 0
    assert any("scipy baseline skipped" in n for n in r["notes"])
    assert "scipy baseline skipped" in (tmp_path / "b1" / "report.md").read_text()
    r0 = bench.run_bench(root, tmp_path / "b0", baseline_every=0, categories="Cup", **fast)
    assert set(r0["runs"]) == {"batched"} and r0["comparison"] is None
    assert r0["selection"]["mesh_ids"] == [21]


def test_bad_human_seg_is_reported_and_exits_1(fake_psb, tmp_path, capsys):
    root, _ = fake_psb
    (root / "gt" / "1" / "1_2.seg").write_text("1\n2\n")          # 2 labels for a whole mesh
    rc = main(["bench", "--psb", str(root), "--out", str(tmp_path / "b"), "--baseline-every", "0",
               "--workers", "1", "--solver", "lanczos", "--categories", "Human"])
    assert rc == 1
    r = json.loads((tmp_path / "b" / "report.json").read_text())
    assert len(r["problems"]) == 1 and "1_2.seg" in r["problems"][0]
    assert r["runs"]["batched"]["meshes_ok"] == 1 and r["selection"]["ks"] == {"1": [2, 3]}
    assert r["settings"]["segment_kwargs"]["solver"] == "lanczos"
    assert "1_2.seg" in (tmp_path / "b" / "report.md").read_text()


def test_budget_sweep_batched_vs_one_at_a_time(fake_psb, tmp_path, capsys):
    """--budgets: the same meshes once one per batch and once per budget, in one run; per
    budget the ratio one-at-a-time seconds / batched seconds (>= 1: batching at least as fast)."""
    root, n_faces = fake_psb
    out = tmp_path / "b"
    assert main(["bench", "--psb", str(root), "--out", str(out), "--baseline-every", "0",
                 "--workers", "1", "--coarse-faces", "0", "--budgets", "100000,300,300"]) == 0
    stdout = capsys.readouterr().out
    r = json.loads((out / "report.json").read_text())
    assert r["settings"]["budgets"] == [300, 100000]                   # sorted, distinct
    assert set(r["runs"]) == {"batched", "one_at_a_time", "budget_300", "budget_100000"}
    sweep = r["budget_sweep"]
    assert sweep["mesh_ids"] == [1, 21] and sweep["faces"] == n_faces   # every mesh: no baselines
    one = r["runs"]["one_at_a_time"]
    assert one["batches"] == 2 and one["batch_faces"] == 1
    # 252 + 312 faces: a budget of 300 holds one mesh a batch, 100000 both; the default budget
    # (run batched, the same meshes here) is a row too, not run again.
    default = r["settings"]["batch_faces"]
    assert [(row["budget"], row["batches"], row["run"]) for row in sweep["rows"]] == sorted(
        [(300, 2, "budget_300"), (100000, 1, "budget_100000"), (default, 1, "batched")])
    for row in sweep["rows"]:
        run = r["runs"][row["run"]]
        assert run["mesh_ids"] == one["mesh_ids"] and run["meshes_ok"] == 2 and row["comparable"]
        assert row["seconds"] == run["wall_seconds"] > 0
        assert abs(row["ratio"] - one["wall_seconds"] / run["wall_seconds"]) < 1e-12
        assert row["stage_ratios"]["akvf"] > 0 and row["stage_ratios"]["segment"] > 0
        assert row["cpu_seconds_each"] == [run["cpu_seconds"]] and run["cpu_seconds"] > 0
        assert abs(row["cpu_ratio"] - one["cpu_seconds"] / run["cpu_seconds"]) < 1e-12
    md = (out / "report.md").read_text()
    assert "## Batched vs one at a time, by face budget" in md and "| 100,000 | 1 |" in md
    assert "by face budget: 300: " in stdout and "100000: " in stdout


def test_budget_sweep_reuses_the_baseline_subset(fake_psb, tmp_path):
    """With baselines on, the sweep runs on their subset and reuses run one_at_a_time."""
    root, _ = fake_psb
    fast = dict(n_fields=16, kmeans_restarts=2, untangle_restarts=1)
    r = bench.run_bench(root, tmp_path / "b", baseline_every=2, budgets=[5000, 1], workers=1,
                        repeats=2, **fast)
    sweep = r["budget_sweep"]
    assert sweep["mesh_ids"] == [1] == r["runs"]["one_at_a_time"]["mesh_ids"]
    assert r["runs"]["budget_5000"]["mesh_ids"] == [1]
    # Budget 1 is the one-at-a-time run itself: no row. Repeats: interleaved, the fastest counts;
    # the first one-at-a-time repetition is the baselines' own run.
    (row,) = sweep["rows"]
    assert row["budget"] == 5000 and len(row["seconds_each"]) == 2 and sweep["repeats"] == 2
    each = sweep["one_at_a_time_seconds_each"]
    assert len(each) == 2 and each[0] == r["runs"]["one_at_a_time"]["wall_seconds"]
    assert row["seconds"] == min(row["seconds_each"]) and row["one_at_a_time_seconds"] == min(each)
    assert row["seconds_each"][0] == r["runs"]["budget_5000"]["wall_seconds"]
    assert abs(row["ratio"] - min(each) / min(row["seconds_each"])) < 1e-12
    assert "2 repetitions, interleaved" in (tmp_path / "b" / "report.md").read_text()
    r0 = bench.run_bench(root, tmp_path / "b0", baseline_every=0, workers=1, **fast)
    assert "budget_sweep" not in r0 and r0["settings"]["budgets"] == [] and r0["partial"] is False


def test_a_stopped_bench_leaves_the_runs_it_finished(fake_psb, tmp_path, monkeypatch):
    """The report is written after every run (partial), so a bench stopped at a time limit
    (benchmarks/device_check.sh) keeps what it measured."""
    root, _ = fake_psb
    real, calls = bench.run_torchakvf, []

    def stop_at_the_second(name, *args, **kwargs):
        calls.append(name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(name, *args, **kwargs)

    monkeypatch.setattr(bench, "run_torchakvf", stop_at_the_second)
    out = tmp_path / "b"
    with pytest.raises(KeyboardInterrupt):
        bench.run_bench(root, out, baseline_every=0, budgets=[300], workers=1, n_fields=16,
                        kmeans_restarts=2, untangle_restarts=1)
    assert calls == ["batched", "one_at_a_time"]
    r = json.loads((out / "report.json").read_text())
    assert r["partial"] is True and set(r["runs"]) == {"batched"}
    assert r["runs"]["batched"]["meshes_ok"] == 2 and r["wall_seconds"] > 0
    assert "Partial report" in (out / "report.md").read_text()
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "report.md"]   # scratch gone




def test_batched_flag_runs_the_accelerator_path_and_is_recorded(fake_psb, tmp_path, capsys, monkeypatch):
    """--batched: every batch through the batched LOBPCG (none on the per-mesh CPU solvers),
    the batched budget, and the flag in the report."""
    from torchakvf.pipeline.batches import BATCHED_BATCH_FACES
    from torchakvf.solvers import group_solver

    calls = []
    real = group_solver.segmented_lobpcg
    monkeypatch.setattr(group_solver, "segmented_lobpcg", lambda *a, **k: calls.append(1) or real(*a, **k))
    root, _ = fake_psb
    out = tmp_path / "b"
    assert main(["bench", "--psb", str(root), "--out", str(out), "--baseline-every", "0",
                 "--workers", "1", "--batched", "--categories", "Human"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["settings"]["segment_kwargs"]["batched"] is True and calls
    assert r["settings"]["batch_faces"] == BATCHED_BATCH_FACES
