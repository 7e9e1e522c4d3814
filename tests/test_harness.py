"""torchakvf.evaluate.harness: the PSB evaluation end to end on a tiny synthetic "PSB", protocols,
resume, settings, the eval command."""
from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest
from helpers.meshfiles import write_off, write_seg

from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.evaluate import metrics as M
from torchakvf.evaluate.harness import evaluate_psb, human_mode, parse_metrics

#: cheap clustering for tests (the same in every call that shares an output folder)
FAST = dict(kmeans_restarts=5, untangle_restarts=2, n_fields=16)


@pytest.fixture(scope="module")
def tiny_psb(tmp_path_factory):
    """Mesh 1 (Human): a dumbbell, humans = its 2 parts, all-zeros, and a 3-part split.
    Mesh 141 (Table, held back): three blobs, no ground truth."""
    root = tmp_path_factory.mktemp("psb")
    d = shapes.dumbbell(n_around=30)
    write_off(root / "meshes" / "1.off.gz", d.vertices, d.faces, gz=True)
    z = d.vertices[d.faces].mean(axis=1)[:, 2]
    three = np.digitize(z, [-1.0, 1.0])           # a human who cut the dumbbell into three
    write_seg(root / "gt" / "1" / "1_0.seg", d.part_labels)
    write_seg(root / "gt" / "1" / "1_1.seg", np.zeros(len(d.faces), dtype=int))
    write_seg(root / "gt" / "1" / "1_2.seg", three)
    write_seg(root / "gt" / "1" / "1_3.seg", d.part_labels)
    t = shapes.three_blobs(n_around=30)
    write_off(root / "meshes" / "141.off", t.vertices, t.faces)
    return root, d


@pytest.fixture(scope="module")
def run_by_seg(tiny_psb, tmp_path_factory):
    root, _ = tiny_psb
    out = tmp_path_factory.mktemp("eval")
    lines = []
    summary = evaluate_psb(root, out, progress=lines.append, **FAST)
    return out, summary, lines


def test_end_to_end_files_and_rows(tiny_psb, run_by_seg):
    root, d = tiny_psb
    out, summary, lines = run_by_seg
    for name in ("scores.csv", "summary.md", "rand_index.png", "settings.json"):
        assert (out / name).is_file(), name
    # human counts of mesh 1: 2, 1, 3, 2 -> distinct k's 1, 2, 3
    for k in (1, 2, 3):
        assert (out / "pred" / "1" / f"1_k{k}.seg").is_file()
    assert (out / "pred" / "141" / "141_k6.seg").is_file()     # no gt: the default k
    rows = list(csv.DictReader((out / "scores.csv").open()))
    assert [r["id"] for r in rows] == ["1", "141"]
    r1, r141 = rows
    assert r1["category"] == "Human" and r1["ks"] == "1;2;3" and r1["status"] == "ok"
    assert int(r1["faces"]) == len(d.faces)
    for col in ("rand_index_error", "hamming_distance", "hamming_missing_rate",
                "hamming_false_alarm_rate", "gce", "lce", "cut_discrepancy", "seconds"):
        assert r1[col] != "" and np.isfinite(float(r1[col])), col
    assert r141["category"] == "Table" and r141["status"] == "no score"
    assert r141["rand_index_error"] == ""
    assert summary.row(141).status == "no score"
    assert summary.counts["Table"] == {"scored": 0, "no score": 1, "failed": 0}
    text = (out / "summary.md").read_text()
    for ref in ("Human", "One segment", "Every face", "Table", "no score", "wall time"):
        assert ref in text
    assert any("batch" in ln for ln in lines)                   # progress was reported


def test_gallery_shows_prediction_beside_a_human_at_the_same_k(tiny_psb, run_by_seg):
    from torchakvf.evaluate import psb as P
    from torchakvf.evaluate.gallery import gallery_item
    from torchakvf.evaluate.metrics import rand_index_error
    from torchakvf.evaluate.plan import find_entries, plan_meshes

    root, d = tiny_psb
    out, summary, _ = run_by_seg
    assert summary.galleries == {"Human": "gallery/Human.png"}        # Table has no score
    assert (out / "gallery" / "Human.png").stat().st_size > 10_000
    assert "[Human](gallery/Human.png)" in (out / "summary.md").read_text()
    plan = plan_meshes(find_entries(root)[0], out, "by-segmentation", False, 6)[0]
    title, v, f, pred, human, err = gallery_item(plan, summary.row(1))
    # the first human (2 parts) beside the prediction made for k = 2
    assert title == "1" and len(f) == len(d.faces) and len(np.unique(pred)) == 2
    np.testing.assert_array_equal(human, d.part_labels)
    np.testing.assert_array_equal(pred, P.read_seg(out / "pred" / "1" / "1_k2.seg"))
    assert err == rand_index_error(pred, d.part_labels) and 0.0 <= err < 0.05


def test_galleries_drawn_in_worker_processes_equal_those_drawn_here(tiny_psb, run_by_seg, tmp_path,
                                                                   monkeypatch):
    """Categories are drawn side by side in worker processes: the same PNG bytes and the same
    {category: path} (in the plans' order) as drawn one after another in this process (a worker
    per mesh allowed, so that two meshes start a pool)."""
    import copy
    import dataclasses
    import shutil

    from torchakvf.evaluate import gallery
    from torchakvf.evaluate.gallery import write_galleries

    monkeypatch.setattr(gallery, "MESHES_PER_GALLERY_WORKER", 1)
    from torchakvf.evaluate.plan import find_entries, plan_meshes

    root, _ = tiny_psb
    out, summary, _ = run_by_seg
    plan = plan_meshes(find_entries(root)[0], out, "by-segmentation", False, 6)[0]
    row = summary.row(1)
    # mesh 1 once more, as mesh 2 of a second category, so that two galleries can be drawn at once
    twin_dir = tmp_path / "pred2"
    twin_dir.mkdir()
    for seg in plan.pred_dir.glob("1_k*.seg"):
        shutil.copy(seg, twin_dir / seg.name.replace("1_k", "2_k"))
    twin = dataclasses.replace(plan, entry=dataclasses.replace(plan.entry, mesh_id=2, category="Cup"),
                               pred_dir=twin_dir)
    twin_row = copy.copy(row)
    twin_row.mesh_id, twin_row.category = 2, "Cup"
    plans, rows = [plan, twin], [row, twin_row]
    got = {}
    for workers in (1, 2):
        got[workers] = write_galleries(tmp_path / f"w{workers}", plans, rows, workers=workers)
        assert list(got[workers]) == ["Human", "Cup"]
    assert got[1] == got[2]
    for rel in got[1].values():
        assert (tmp_path / "w1" / rel).read_bytes() == (tmp_path / "w2" / rel).read_bytes()


def test_few_meshes_are_drawn_in_this_process(tiny_psb, run_by_seg, monkeypatch):
    """write_galleries asks map_batches for one process (no pool) for a run's few meshes, however
    many workers the run has."""
    from torchakvf.evaluate import gallery
    from torchakvf.evaluate.plan import find_entries, plan_meshes

    root, _ = tiny_psb
    out, summary, _ = run_by_seg
    plan = plan_meshes(find_entries(root)[0], out, "by-segmentation", False, 6)[0]
    asked = []
    real = gallery.map_batches

    def spy(batches, fn, args=(), *, workers=1, **kw):
        asked.append(workers)
        return real(batches, fn, args, workers=workers, **kw)

    monkeypatch.setattr(gallery, "map_batches", spy)
    assert gallery.write_galleries(out, [plan], [summary.row(1)], workers=4) == {"Human": "gallery/Human.png"}
    assert asked == [1]


def test_predictions_of_another_method_are_not_resumed(tiny_psb, run_by_seg):
    root, _ = tiny_psb
    out, summary, _ = run_by_seg             # made with the default method, "merge"
    assert json.loads((out / "settings.json").read_text())["prediction"]["method"] == "merge"
    with pytest.raises(TorchAKVFError, match="method"):
        evaluate_psb(root, out, progress=False, method="paper", **FAST)


def test_predictions_made_under_other_defaults_are_not_resumed(tiny_psb, run_by_seg):
    """Every segment option is recorded, also the defaults: a folder made under another default
    (here: the graph cut, as an older release had none) is refused, not resumed."""
    root, _ = tiny_psb
    out, _, _ = run_by_seg
    recorded = json.loads((out / "settings.json").read_text())["prediction"]["options"]
    assert recorded["graphcut"] is not None and recorded["merge"]["ratio"] > 1
    assert recorded["kmeans_restarts"] == FAST["kmeans_restarts"]
    settings = out / "settings.json"
    original = settings.read_text()          # the folder is shared by this module's tests
    doc = json.loads(original)
    doc["prediction"]["options"]["graphcut"] = None            # as if made without the cut
    try:
        settings.write_text(json.dumps(doc))
        with pytest.raises(TorchAKVFError, match="options"):
            evaluate_psb(root, out, progress=False, **FAST)
    finally:
        settings.write_text(original)


def test_merge_weights_are_recorded_in_the_settings(tiny_psb, tmp_path):
    from torchakvf.options import MergeWeights, SegmentOptions

    root, _ = tiny_psb
    evaluate_psb(root, tmp_path, progress=False, metrics="rand", plot=False, ids="1",
                 merge=MergeWeights(concavity=8.0), **FAST)
    rec = json.loads((tmp_path / "settings.json").read_text())["prediction"]["segment_kwargs"]
    # every field (the over-segmentation's too), the one given changed
    assert rec["merge"] == dict(SegmentOptions().merge_record(), concavity=8.0)
    assert rec["merge"]["concavity"] == 8.0 and MergeWeights().concavity != 8.0


def test_dumbbell_two_part_human_is_matched(tiny_psb, run_by_seg):
    root, d = tiny_psb
    out, summary, _ = run_by_seg
    pred2 = np.loadtxt(out / "pred" / "1" / "1_k2.seg", dtype=np.int64)
    assert M.rand_index_error(pred2, d.part_labels) < 0.05
    # by-segmentation: the mesh score is the mean over its 4 humans, each vs its own k
    pred = {k: np.loadtxt(out / "pred" / "1" / f"1_k{k}.seg", dtype=np.int64) for k in (1, 2, 3)}
    gts = [np.loadtxt(root / "gt" / "1" / f"1_{j}.seg", dtype=np.int64) for j in range(4)]
    expect = np.mean([M.rand_index_error(pred[len(np.unique(g))], g) for g in gts])
    assert summary.row(1).metrics["rand_index_error"] == pytest.approx(expect)


def test_one_segment_reference_by_hand(tiny_psb, run_by_seg):
    root, d = tiny_psb
    _, summary, _ = run_by_seg
    gts = [np.loadtxt(root / "gt" / "1" / f"1_{j}.seg", dtype=np.int64) for j in range(4)]
    zeros = np.zeros(len(d.faces), dtype=np.int64)
    by_hand = [M.evaluate_segmentation(d.vertices, d.faces, zeros, g) for g in gts]
    one = summary.row(1).references["One segment"]
    assert one["rand_index_error"] == pytest.approx(np.mean([m["rand_index_error"] for m in by_hand]))
    assert one["hamming_distance"] == pytest.approx(np.mean([m["hamming_distance"] for m in by_hand]))
    assert one["gce"] == pytest.approx(0.0, abs=1e-12)
    every = summary.row(1).references["Every face"]["rand_index_error"]
    assert one["rand_index_error"] + every == pytest.approx(1.0)
    assert summary.references["One segment"]["Human"]["rand_index_error"] == \
        pytest.approx(one["rand_index_error"])


def test_resume_skips_recompute(tiny_psb, run_by_seg):
    root, _ = tiny_psb
    out, first, _ = run_by_seg
    seg = out / "pred" / "1" / "1_k2.seg"
    before = seg.stat().st_mtime_ns
    lines = []
    again = evaluate_psb(root, out, progress=lines.append, **FAST)
    assert seg.stat().st_mtime_ns == before
    assert not any("batch" in ln for ln in lines)               # nothing was solved
    assert again.row(1).metrics == pytest.approx(first.row(1).metrics, nan_ok=True)
    # other prediction settings in the same folder are refused
    with pytest.raises(TorchAKVFError, match="other settings"):
        evaluate_psb(root, out, seed=1, progress=False, **FAST)


def test_by_model_uses_the_mode(tiny_psb, run_by_seg, tmp_path):
    root, _ = tiny_psb
    out, _, _ = run_by_seg
    # humans' counts 2, 1, 3, 2 -> mode 2; predictions are shared with the by-seg run (resume)
    s = evaluate_psb(root, out, protocol="by-model", progress=False, metrics="rand,gce", **FAST)
    row = s.row(1)
    assert row.ks == [2] and row.human_mode == 2
    pred2 = np.loadtxt(out / "pred" / "1" / "1_k2.seg", dtype=np.int64)
    gts = [np.loadtxt(root / "gt" / "1" / f"1_{j}.seg", dtype=np.int64) for j in range(4)]
    assert row.metrics["rand_index_error"] == pytest.approx(
        np.mean([M.rand_index_error(pred2, g) for g in gts]))
    assert set(row.metrics) == {"rand_index_error", "gce"}
    assert human_mode([3, 2, 3, 2, 5]) == 2


def test_selection_errors(tiny_psb, tmp_path):
    root, _ = tiny_psb
    with pytest.raises(TorchAKVFError, match="unknown PSB category"):
        evaluate_psb(root, tmp_path, categories="Humans", progress=False)
    with pytest.raises(TorchAKVFError, match="no meshes"):
        evaluate_psb(root, tmp_path, categories=["Spring"], progress=False)
    with pytest.raises(TorchAKVFError, match="not found"):
        evaluate_psb(root, tmp_path, ids=[2], progress=False)
    with pytest.raises(TorchAKVFError, match="protocol"):
        evaluate_psb(root, tmp_path, protocol="bySegmentation", progress=False)
    with pytest.raises(TorchAKVFError, match="unknown metric"):
        parse_metrics("rand,foo")
    with pytest.raises(TorchAKVFError, match="remedy"):
        evaluate_psb(root, tmp_path, remedy="magic", progress=False)
    with pytest.raises(TorchAKVFError, match="does not exist"):
        evaluate_psb(tmp_path / "nope", tmp_path, progress=False)


def test_eval_command_parses_and_validates(tiny_psb, tmp_path):
    from torchakvf.evaluate.commands import add_eval_command

    root, _ = tiny_psb
    parser = argparse.ArgumentParser()
    add_eval_command(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["eval", "--psb", str(root), "--out", str(tmp_path / "e"),
                              "--categories", "Human,Octopus", "--protocol", "by-model",
                              "--metrics", "rand", "--ids", "1", "--quiet", "--n-fields", "16"])
    assert args.protocol == "by-model" and args.k is None
    assert args.func(args) == 0
    assert (tmp_path / "e" / "pred" / "1" / "1_k2.seg").is_file()
    bad = parser.parse_args(["eval", "--psb", str(root), "--categories", "Human,Robot"])
    with pytest.raises(TorchAKVFError, match="Robot"):
        bad.func(bad)
    missing = parser.parse_args(["eval", "--psb", str(tmp_path / "nowhere")])
    with pytest.raises(TorchAKVFError, match="no PSB data"):
        missing.func(missing)


def test_eval_without_psb_says_what_to_pass(tmp_path, monkeypatch, capsys):
    """No --psb and no $TORCHAKVF_PSB: one line naming both (the package looks nowhere else,
    not beside the checkout), exit 2; the variable alone is enough."""
    from torchakvf.cli import main

    monkeypatch.delenv("TORCHAKVF_PSB", raising=False)
    assert main(["eval", "--out", str(tmp_path / "e"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pass --psb DIR" in err and "TORCHAKVF_PSB" in err
    monkeypatch.setenv("TORCHAKVF_PSB", str(tmp_path / "nowhere"))
    assert main(["eval", "--out", str(tmp_path / "e"), "--quiet"]) == 2
    assert "no PSB data at " + str(tmp_path / "nowhere") in capsys.readouterr().err


def test_k_auto_end_to_end(tiny_psb, tmp_path):
    root, d = tiny_psb
    s = evaluate_psb(root, tmp_path, ids=[1], k_mode="auto", k_range=(1, 3), progress=False,
                     metrics="rand", **FAST)
    row = s.row(1)
    assert row.k_auto["chosen"] in (2,)                      # the dumbbell's elbow is at 2
    assert (tmp_path / "pred" / "1" / "1_k2.seg").is_file()
    assert set(row.k_auto["rand_index_error_by_k"]) == {1, 2, 3}
    assert "Automatic k" in (tmp_path / "summary.md").read_text()
    assert s.k_auto["overall"]["hit_rate"] == 1.0            # human mode 2


def test_real_psb_one_mesh(psb, tmp_path):
    """A small labelled PSB mesh (Hand 200, 3,026 faces; its eigensolve converges quickly)."""
    s = evaluate_psb(psb, tmp_path, ids=[200], protocol="by-model",
                     progress=False, metrics="rand,hamming", **FAST)
    row = s.rows[0]
    assert row.status == "ok" and row.converged is True
    # by-model: the prediction at the humans' most common count against every human, by an
    # independent pair count (contingency table), not the package's metric.
    from torchakvf.evaluate.psb import read_seg
    gts = [read_seg(p) for p in sorted((psb / "gt" / "200").glob("200_*.seg*"))]
    mode = human_mode([len(np.unique(g)) for g in gts])
    assert row.ks == [mode]
    pred = np.loadtxt(tmp_path / "pred" / "200" / f"200_k{mode}.seg", dtype=np.int64)
    assert len(np.unique(pred)) == mode

    def pair_error(a, b):
        n = len(a)
        table = np.zeros((a.max() + 1, b.max() + 1))
        np.add.at(table, (a, b), 1)
        same = lambda c: (c * (c - 1) / 2).sum()
        return (same(table.sum(1)) + same(table.sum(0)) - 2 * same(table)) / (n * (n - 1) / 2)

    expect = np.mean([pair_error(pred - pred.min(), g - g.min()) for g in gts])
    assert row.metrics["rand_index_error"] == pytest.approx(expect, rel=1e-9)
    one = np.mean([pair_error(np.zeros_like(g), g - g.min()) for g in gts])
    assert row.references["One segment"]["rand_index_error"] == pytest.approx(one, rel=1e-9)
    # The method beats putting every face in one segment on this hand.
    assert row.metrics["rand_index_error"] < one
    assert (tmp_path / "rand_index.png").stat().st_size > 1000


# ---- bad inputs: reported one per line, the rest still scored --------------------------------

@pytest.fixture(scope="module")
def good_psb(tmp_path_factory):
    """Mesh 1 (Human): a small dumbbell with two usable humans (its 2 parts, a 3-part cut), and
    an evaluation of it already in ``out`` (so each case below only scores)."""
    root = tmp_path_factory.mktemp("good_psb")
    d = shapes.dumbbell(n_around=12)
    write_off(root / "meshes" / "1.off", d.vertices, d.faces)
    z = d.vertices[d.faces].mean(axis=1)[:, 2]
    write_seg(root / "gt" / "1" / "1_0.seg", d.part_labels)
    write_seg(root / "gt" / "1" / "1_1.seg", np.digitize(z, [-0.5, 0.5]))
    out = tmp_path_factory.mktemp("good_eval")
    s = evaluate_psb(root, out, progress=False, metrics="rand", plot=False, **FAST)
    assert not s.failed and s.row(1).scored
    return root, out, d


def _bad_input(kind, root, d):
    """Adds one bad input to a PSB copy; returns the file the report must name."""
    n = len(d.faces)
    if kind == "wrong line count":
        return write_seg(root / "gt" / "1" / "1_2.seg", np.zeros(n - 3, dtype=int))
    if kind == "non-integer label":
        path = write_seg(root / "gt" / "1" / "1_2.seg", np.zeros(n, dtype=int))
        path.write_text(path.read_text().replace("0\n", "zero\n", 1))
        return path
    if kind == "empty seg":
        path = root / "gt" / "1" / "1_2.seg"
        path.write_text("")
        return path
    if kind == "seg in the wrong folder":
        return write_seg(root / "gt" / "1" / "21_0.seg", np.zeros(n, dtype=int))
    if kind == "mesh id outside 1..400":
        return write_off(root / "meshes" / "401.off", d.vertices, d.faces)
    if kind == "unreadable mesh header":
        path = root / "meshes" / "41.off"
        path.write_text("OFF\nmany some none\n0 0 0\n")
        return path
    raise AssertionError(kind)


BAD_INPUTS = ["wrong line count", "non-integer label", "empty seg", "seg in the wrong folder",
              "mesh id outside 1..400", "unreadable mesh header"]


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_bad_input_is_reported_and_the_rest_scored(good_psb, tmp_path, kind):
    import shutil

    good_root, good_out, d = good_psb
    root, out = tmp_path / "psb", tmp_path / "eval"
    shutil.copytree(good_root, root)
    shutil.copytree(good_out, out)
    bad = _bad_input(kind, root, d)
    lines = []
    s = evaluate_psb(root, out, progress=lines.append, metrics="rand", plot=False, **FAST)
    assert s.failed
    said = [ln for ln in lines if bad.name in ln]
    assert len(said) == 1, lines                       # one line, naming the file
    text = (out / "summary.md").read_text()
    assert bad.name in text
    # Mesh 1 is still scored, against its two usable humans only.
    row = s.row(1)
    assert row.scored
    pred = {k: np.loadtxt(out / "pred" / "1" / f"1_k{k}.seg", dtype=np.int64) for k in (2, 3)}
    gts = [np.loadtxt(root / "gt" / "1" / f"1_{j}.seg", dtype=np.int64) for j in (0, 1)]
    expect = np.mean([M.rand_index_error(pred[len(np.unique(g))], g) for g in gts])
    assert row.metrics["rand_index_error"] == pytest.approx(expect, rel=1e-12)
    if kind == "unreadable mesh header":
        assert s.row(41).status.startswith("failed") and "41.off" in s.row(41).status
        rows = list(csv.DictReader((out / "scores.csv").open()))
        assert [r["id"] for r in rows] == ["1", "41"] and rows[1]["status"].startswith("failed")
    if kind == "wrong line count":
        assert f"{len(d.faces) - 3} labels" in said[0]


def test_corrupt_meta_file_is_reported_not_replaced(good_psb, tmp_path):
    import shutil

    good_root, good_out, _ = good_psb
    out = tmp_path / "eval"
    shutil.copytree(good_out, out)
    meta = out / "pred" / "1" / "1_meta.json"
    meta.write_text('{"faces": 12, "seconds":')           # torn
    lines = []
    s = evaluate_psb(good_root, out, progress=lines.append, metrics="rand", plot=False, **FAST)
    assert s.failed and s.row(1).status.startswith("failed") and "meta" in s.row(1).status
    assert any("1_meta.json" in ln and "corrupt" in ln for ln in lines)
    assert meta.read_text() == '{"faces": 12, "seconds":'
    assert "1_meta.json" in (out / "summary.md").read_text()


def test_eval_command_exits_non_zero_when_a_mesh_fails(good_psb, tmp_path, capsys):
    import shutil

    from torchakvf.cli import main

    good_root, _, d = good_psb
    root = tmp_path / "psb"
    shutil.copytree(good_root, root)
    _bad_input("unreadable mesh header", root, d)
    rc = main(["eval", "--psb", str(root), "--out", str(tmp_path / "e"), "--metrics", "rand",
               "--ids", "41", "--quiet", "--workers", "1"])
    out = capsys.readouterr().out
    assert rc == 1
    assert "41.off" in out and "1 failed" in out
    assert (tmp_path / "e" / "summary.md").is_file()


def test_eval_on_cuda_matches_cpu(good_psb, tmp_path, cuda):
    """The same predictions on the GPU (LOBPCG there) as on the CPU, up to faces near a boundary."""
    root, cpu_out, d = good_psb
    s = evaluate_psb(root, tmp_path, progress=False, metrics="rand", plot=False, device=str(cuda),
                     **FAST)
    assert s.row(1).scored and not s.failed
    for k in (2, 3):
        gpu = np.loadtxt(tmp_path / "pred" / "1" / f"1_k{k}.seg", dtype=np.int64)
        cpu = np.loadtxt(cpu_out / "pred" / "1" / f"1_k{k}.seg", dtype=np.int64)
        assert M.matched_agreement(gpu, cpu) >= 0.99, k


