"""torchakvf.evaluate.eval_task: the evaluation as a corpus-runner task. On the batched path
(host workers feed the solving process and cut its batches) it gives the single-process
batched path's files bit for bit, finishes every (mesh, k) on real PSB meshes (mesh 114, which
no shift factors decimated, included) and scores as the per-mesh path does; a failing batch is
bisected. Resume: a re-run predicts nothing that is there, an interrupted run is finished by
the next, and a folder written before the runner held evaluations (no manifest) resumes."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from helpers.meshfiles import write_off, write_seg

from torchakvf import shapes
from torchakvf.evaluate.harness import evaluate_psb

#: cheap settings for tests (one k per mesh, small fields, 1-RI only)
FAST = dict(kmeans_restarts=2, untangle_restarts=1, n_fields=8, metrics="rand", plot=False)


@pytest.fixture(scope="module")
def shapes_psb(tmp_path_factory):
    """Three built-in shapes as PSB meshes 1, 2, 3 with their true parts as the human."""
    root = tmp_path_factory.mktemp("psb")
    for i, s in enumerate((shapes.dumbbell(n_around=16), shapes.three_blobs(n_around=16),
                           shapes.dumbbell(n_around=20)), 1):
        write_off(root / "meshes" / f"{i}.off", s.vertices, s.faces)
        write_seg(root / "gt" / str(i) / f"{i}_0.seg", s.part_labels)
    return root


def _predictions(out) -> dict:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted((out / "pred").rglob("*.seg"))}


def _scores(out) -> dict:
    return {int(r["id"]): r for r in csv.DictReader((out / "scores.csv").open())}


def test_host_workers_give_the_single_process_files(shapes_psb, tmp_path):
    """Cut in host processes or in the solving process: the same bytes (a mesh's cut reads
    its own rows only, shipped whole)."""
    runs = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        evaluate_psb(shapes_psb, out, progress=False, batched=True, workers=workers, **FAST)
        runs[workers] = out
    a, b = _predictions(runs[1]), _predictions(runs[2])
    assert sorted(a) == ["pred/1/1_k2.seg", "pred/2/2_k3.seg", "pred/3/3_k2.seg"] and a == b
    sa, sb = _scores(runs[1]), _scores(runs[2])
    assert {i: sa[i]["rand_index_error"] for i in sa} == {i: sb[i]["rand_index_error"] for i in sb}
    rec = json.loads((runs[2] / "settings.json").read_text())
    assert rec["prediction"]["options"]["batched"] is True
    t = rec["run"]["timings"]
    assert t["workers"] == 1 and t["batches"] >= 1 and t["akvf"] > 0 and t["cut"] > 0
    assert 0 <= t["host_share"] <= 1
    t1 = json.loads((runs[1] / "settings.json").read_text())["run"]["timings"]
    assert t1["workers"] == 0 and t1["prepare"] > 0


def test_a_batch_that_fails_is_bisected(shapes_psb, tmp_path, monkeypatch):
    """Mesh 2 makes any batch holding it raise: it fails alone, meshes 1 and 3 are predicted,
    and no mesh is solved alone beside it more than the bisection needs."""
    from torchakvf.evaluate import eval_task

    solved = []
    real = eval_task.solve_akvfs

    def poisoned(batch, n, opts):
        names = [m.name for m in batch.meshes]
        solved.append(names)
        if any(name.endswith("2.off") for name in names):
            raise RuntimeError("cholespy: factorization failed")
        return real(batch, n, opts)

    monkeypatch.setattr(eval_task, "solve_akvfs", poisoned)
    out = tmp_path / "out"
    summary = evaluate_psb(shapes_psb, out, progress=False, batched=True, workers=1, **FAST)
    rows = {r.mesh_id: r for r in summary.rows}
    assert rows[2].status.startswith("failed") and "factorization failed" in rows[2].status
    assert rows[1].status == rows[3].status == "ok"
    assert sorted(_predictions(out)) == ["pred/1/1_k2.seg", "pred/3/3_k2.seg"]
    # [a, b, c] -> halves [a, b] + [c] -> ...: a good mesh is solved at most 1 + log2(3) times
    assert len(solved[0]) == 3 and max(sum(n in s for s in solved) for n in solved[0]) <= 3
    assert sum(len(s) == 1 and s[0].endswith("2.off") for s in solved) == 1
    assert json.loads((out / "settings.json").read_text())["run"]["timings"]["bisections"] >= 1


#: 1-RI tolerance per mesh between the batched path and the per-mesh path with the same
#: eigensolver (LOBPCG): the two differ only by the factor (one block-diagonal factor of the
#: batch against one per mesh), i.e. by round-off, which can still move a near-tied boundary face
#: or merge; measured 0 on these meshes.
SAME_SOLVER_RI_TOL = 0.03
#: 1-RI tolerance on the mean over the meshes against the default per-mesh path (CHOLMOD Krylov /
#: Lanczos). Both agree on the eigenpairs to the solve's tolerance, but a degenerate eigenspace
#: (the PSB's symmetric humans, airplanes, chairs) has no preferred basis: its fields come out
#: rotated, k-means and the merge land on another of near-equal optima, and a mesh's labels can
#: swap one part (mesh 4 at 600 faces: 0.098 against 0.199). One such swap among three meshes
#: moves the mean by about 0.035.
MEAN_RI_TOL = 0.05


def test_batched_eval_on_psb_with_mesh_114(psb, tmp_path):
    """Every stage through the accelerator's path on real meshes, 114 included (no shift
    factors it decimated: it is solved at full resolution, alone); every (mesh, k) predicted;
    1-RI as the per-mesh path's with the same eigensolver within :data:`SAME_SOLVER_RI_TOL`, and
    as the default per-mesh path's on the mean within :data:`MEAN_RI_TOL`."""
    ids = [61, 114, 4]
    common = dict(ids=ids, protocol="by-model", coarse_faces=600, **FAST)
    scores = {}
    for name, kw in (("batched", dict(batched=True)), ("alone", dict(batched=False)),
                     ("alone_lobpcg", dict(batched=False, solver="lobpcg"))):
        out = tmp_path / name
        summary = evaluate_psb(psb, out, progress=False, workers=2, **common, **kw)
        assert not summary.failed and all(r.status == "ok" for r in summary.rows)
        for r in summary.rows:
            assert all((out / "pred" / str(r.mesh_id) / f"{r.mesh_id}_k{k}.seg").is_file() for k in r.ks)
        scores[name] = np.array([float(_scores(out)[i]["rand_index_error"]) for i in ids])
    meta = json.loads((tmp_path / "batched" / "pred" / "114" / "114_meta.json").read_text())
    assert meta["converged"] and "full_resolution_because" in meta
    same_solver = np.abs(scores["batched"] - scores["alone_lobpcg"])
    assert same_solver.max() <= SAME_SOLVER_RI_TOL, same_solver
    assert abs(scores["batched"].mean() - scores["alone"].mean()) <= MEAN_RI_TOL, scores


def test_eval_command_batched(shapes_psb, tmp_path, capsys):
    """``torchakvf eval --batched`` on the CPU: the batched path (its timings recorded), a
    memory budget of one mesh's arrays giving one batch per mesh."""
    from torchakvf.cli import main
    from torchakvf.pipeline.batches import solve_bytes

    out = tmp_path / "out"
    one_mesh = solve_bytes(int(1.5 * 492) + 1, 1, 8)
    assert main(["eval", "--psb", str(shapes_psb), "--out", str(out), "--batched", "--workers", "1",
                 "--n-fields", "8", "--metrics", "rand", "--protocol", "by-model", "--quiet",
                 "--batch-bytes", str(one_mesh)]) == 0
    rec = json.loads((out / "settings.json").read_text())
    assert rec["prediction"]["options"]["batched"] is True
    assert rec["run"]["timings"]["batches"] == 3 and rec["run"]["batch_faces"] > 10 ** 5


def _mtimes(out) -> dict:
    return {p.relative_to(out).as_posix(): p.stat().st_mtime_ns for p in sorted((out / "pred").rglob("*.seg"))}


def test_interrupted_run_is_finished_by_the_next(shapes_psb, tmp_path):
    """Ctrl-C after the first mesh: its predictions stay, the re-run predicts only the other two,
    and the folder ends as a straight run's (same bytes, same scores); a third run solves nothing."""
    straight = tmp_path / "straight"
    evaluate_psb(shapes_psb, straight, progress=False, workers=1, batch_faces=1, **FAST)
    out = tmp_path / "out"

    def stop(line):
        if line.startswith("batch 1:"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        evaluate_psb(shapes_psb, out, progress=stop, workers=1, batch_faces=1, **FAST)
    first = _mtimes(out)
    assert len(first) == 1
    lines = []
    evaluate_psb(shapes_psb, out, progress=lines.append, workers=1, batch_faces=1, **FAST)
    assert sum(ln.startswith("batch ") for ln in lines) == 2
    assert {k: v for k, v in _mtimes(out).items() if k in first} == first
    assert _predictions(out) == _predictions(straight)
    assert {i: r["rand_index_error"] for i, r in _scores(out).items()} == \
        {i: r["rand_index_error"] for i, r in _scores(straight).items()}
    lines.clear()
    evaluate_psb(shapes_psb, out, progress=lines.append, workers=1, batch_faces=1, **FAST)
    assert not any(ln.startswith("batch ") for ln in lines)


def test_a_folder_without_manifest_resumes_and_the_manifest_carries_the_rows(shapes_psb, tmp_path):
    """Resume reads the prediction files, not the manifest: a folder written before evaluations
    had one is resumed, nothing solved; each manifest line of a run carries its mesh's row."""
    out = tmp_path / "out"
    first = evaluate_psb(shapes_psb, out, progress=False, workers=1, **FAST)
    records = [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]
    assert sorted(r["score"]["mesh_id"] for r in records) == [1, 2, 3]
    for r in records:
        assert r["task"] == "eval" and r["status"] == "ok"
        assert r["score"]["metrics"] == pytest.approx(first.row(r["score"]["mesh_id"]).metrics)
        assert set(r["outputs"]) == {f"{r['stem']}_k{r['score']['ks'][0]}.seg", f"{r['stem']}_meta.json"}
    before = _mtimes(out)
    (out / "manifest.jsonl").unlink()
    lines = []
    again = evaluate_psb(shapes_psb, out, progress=lines.append, workers=1, **FAST)
    assert not any(ln.startswith("batch ") for ln in lines) and _mtimes(out) == before
    assert [r.metrics for r in again.rows] == [r.metrics for r in first.rows]
