"""torchakvf.pipeline.commands: the ``segment`` and ``features`` commands (arguments, one-line
errors, exit codes)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.faketask import assert_one_line_error
from helpers.meshfiles import write_off
from helpers.runs import by_stem, cli_run

from torchakvf import shapes

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

REPO = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")


def test_segment_end_to_end(tmp_path, capsys):
    s = shapes.dumbbell(n_around=18)
    src = write_off(tmp_path / "in" / "dumb.off", s.vertices, s.faces)
    out = tmp_path / "segs"
    rc, stdout, err = cli_run(["segment", str(src), "-k", "2", "--out", str(out), "--n-fields", "8",
                               "--formats", "seg,npz,ply"], capsys)
    assert rc == 0, err
    assert "1 ok, 0 failed" in stdout
    labels = np.loadtxt(out / "dumb.seg", dtype=int)
    assert labels.shape == (len(s.faces),) and set(labels.tolist()) == {0, 1}
    # The two ends of the dumbbell, up to the label permutation (a constant labelling scores 0.5).
    from torchakvf.evaluate.metrics import matched_agreement
    assert matched_agreement(labels, s.part_labels) >= 0.95
    assert (out / "dumb.ply").exists() and not (out / "dumb.png").exists()
    rec = by_stem(out)["dumb"]
    assert rec["status"] == "ok" and set(rec["seconds"]) == {"load", "akvf", "untangle", "cluster", "write"}
    assert rec["params"]["solver"] == "auto" and rec["params"]["method"] == "merge"   # the defaults
    rc, stdout, _ = cli_run(["segment", str(src), "-k", "2", "--out", str(out), "--n-fields", "8",
                             "--formats", "seg,npz,ply"], capsys)
    assert rc == 0 and "1 skipped" in stdout



def test_segment_k_auto_records_the_k_each_mesh_got(tmp_path, capsys):
    s = shapes.dumbbell(n_around=18)
    src = write_off(tmp_path / "in" / "dumb.off", s.vertices, s.faces)
    out = tmp_path / "auto"
    rc, stdout, err = cli_run(["segment", str(src), "-k", "auto", "--k-range", "1,3", "--out", str(out),
                               "--formats", "seg"], capsys)
    assert rc == 0, err
    rec = by_stem(out)["dumb"]
    assert rec["k"] == 2 and rec["params"]["k"] == "auto" and rec["params"]["k_range"] == [1, 3]
    assert rec["params"]["merge"]["min_k"] == 1             # the scan's merge weights, as eval -k auto
    labels = np.loadtxt(out / "dumb.seg", dtype=int)
    from torchakvf.evaluate.metrics import matched_agreement
    assert set(labels.tolist()) == {0, 1} and matched_agreement(labels, s.part_labels) >= 0.95
    # --batched runs k auto whole in the solving process: the same calls, the same file
    rc, stdout, err = cli_run(["segment", str(src), "-k", "auto", "--k-range", "1,3", "--out", str(tmp_path / "b"),
                               "--formats", "seg", "--batched"], capsys)
    assert rc == 0, err
    assert (tmp_path / "b" / "dumb.seg").read_bytes() == (out / "dumb.seg").read_bytes()
    # every output format, the .npz holding the choice as plain arrays
    rc, _, err = cli_run(["segment", str(src), "-k", "auto", "--k-range", "1,3", "--out", str(tmp_path / "all")],
                         capsys)
    assert rc == 0, err
    with np.load(tmp_path / "all" / "dumb.npz", allow_pickle=False) as z:
        assert z["param_k_auto_ks"].tolist() == [1, 2, 3] and int(z["param_k"]) == 2
    # the k given: no k recorded beside the parameters (manifests of earlier runs still resume)
    rc, _, err = cli_run(["segment", str(src), "-k", "2", "--out", str(tmp_path / "two"), "--formats", "seg"], capsys)
    assert rc == 0, err
    assert "k" not in by_stem(tmp_path / "two")["dumb"]
    assert "k_range" not in by_stem(tmp_path / "two")["dumb"]["params"]


@pytest.mark.parametrize("argv, message", [
    (["segment", "{tmp}/nope.off", "-k", "2", "--out", "{tmp}/o"], "nope.off: file not found"),
    (["segment", "{src}", "-k", "0", "--out", "{tmp}/o"], "-k must be an integer >= 1"),
    (["segment", "{src}", "-k", "two", "--out", "{tmp}/o"], "-k must be an integer"),
    (["segment", "{src}", "-k", "auto", "--k-range", "3", "--out", "{tmp}/o"], "--k-range must be LO,HI"),
    (["segment", "{src}", "-k", "auto", "--k-range", "2,3", "--out", "{tmp}/o"], "k_max >= k_min + 2"),
    (["segment", "{src}", "-k", "2", "--out", "{src}/sub"], "cannot create or write the output folder"),
    (["segment", "{src}", "-k", "2", "--formats", "seg,gif", "--out", "{tmp}/o"], "unknown format 'gif'"),
    (["features", "{src}", "--n", "-3", "--out", "{tmp}/o"], "--n must be an integer >= 1"),
    (["features", "{src}", "--batch-faces", "lots", "--out", "{tmp}/o"], "--batch-faces must be an integer"),
    # out-of-range values are argument errors, not per-mesh failures or silent nonsense
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
    rc, out, err = cli_run(argv, capsys)
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
    rc, out, err = cli_run(["segment", str(src), "-k", "100", "--out", str(tmp_path / "o")], capsys)
    assert rc == 1
    assert "0 ok, 1 failed" in out and "larger than the mesh's 80 faces" in out
    rec = by_stem(tmp_path / "o")["m"]
    assert rec["status"] == "failed" and "-k 100" in rec["error"]
    assert "Traceback" not in err


@pytest.mark.parametrize("command", [["segment", "-k", "2", "--n-fields", "8", "--formats", "seg"],
                                     ["features", "--n", "8"]])
def test_batched_flag_solves_batches_as_one_and_is_recorded(tmp_path, capsys, monkeypatch, command):
    """--batched on the CPU: the batch through the batched LOBPCG (the accelerator's path, not the
    per-mesh CPU solvers), recorded in the manifest's params; without it the params are as
    before (earlier manifests resume)."""
    from torchakvf.solvers import group_solver

    calls = []
    real = group_solver.segmented_lobpcg
    monkeypatch.setattr(group_solver, "segmented_lobpcg", lambda *a, **k: calls.append(1) or real(*a, **k))
    s = shapes.dumbbell(n_around=12)
    srcs = [write_off(tmp_path / "in" / f"{n}.off", s.vertices, s.faces) for n in ("a", "b")]
    rc, stdout, err = cli_run([command[0], *srcs, "--out", tmp_path / "b", *command[1:], "--batched"], capsys)
    assert rc == 0 and "2 ok, 0 failed" in stdout, err
    assert calls and all(r["params"]["batched"] is True for r in by_stem(tmp_path / "b").values())
    calls.clear()
    rc, stdout, err = cli_run([command[0], *srcs, "--out", tmp_path / "p", *command[1:]], capsys)
    assert rc == 0 and not calls
    assert all("batched" not in r["params"] for r in by_stem(tmp_path / "p").values())


def test_second_merge_flag_is_recorded(tmp_path, capsys):
    """--second-merge off: the manifest records no second merge (merge_choice None); by default
    it records the ConcaveChoice (ratio 3, floor 0.05), so a run resumed under the other setting
    redoes its meshes."""
    s = shapes.dumbbell(n_around=12)
    src = write_off(tmp_path / "in" / "a.off", s.vertices, s.faces)
    for flag, out in ((["--second-merge", "off"], "off"), ([], "on")):
        rc, stdout, err = cli_run(["segment", src, "--out", tmp_path / out, "-k", "2", "--n-fields", "8",
                                   "--formats", "seg", *flag], capsys)
        assert rc == 0 and "1 ok, 0 failed" in stdout, err
    assert by_stem(tmp_path / "off")["a"]["params"]["merge_choice"] is None
    on = by_stem(tmp_path / "on")["a"]["params"]["merge_choice"]
    assert (on["ratio"], on["floor"]) == (3.0, 0.05)


def test_sheet_rule_flag_is_recorded(tmp_path, capsys):
    """--sheet-rule off: both merges' weights record no sheet rule (sheet_flatness None), with
    the second merge on or off; by default both record 0.9."""
    s = shapes.dumbbell(n_around=12)
    src = write_off(tmp_path / "in" / "a.off", s.vertices, s.faces)
    runs = {"on": [], "off": ["--sheet-rule", "off"], "off2": ["--sheet-rule", "off", "--second-merge", "off"]}
    for out, flag in runs.items():
        rc, stdout, err = cli_run(["segment", src, "--out", tmp_path / out, "-k", "2", "--n-fields", "8",
                                   "--formats", "seg", *flag], capsys)
        assert rc == 0 and "1 ok, 0 failed" in stdout, err
    on, off, off2 = (by_stem(tmp_path / out)["a"]["params"] for out in runs)
    assert on["merge"]["sheet_flatness"] == 0.9 and on["merge_choice"]["weights"]["sheet_flatness"] == 0.9
    assert off["merge"]["sheet_flatness"] is None and off["merge_choice"]["weights"]["sheet_flatness"] is None
    assert off["merge_choice"]["weights"]["concavity"] == 16.0          # the hand-set cost otherwise
    assert off2["merge"]["sheet_flatness"] is None and off2["merge_choice"] is None
