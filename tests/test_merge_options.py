"""Method "merge"'s options (:mod:`torchakvf.merge_options`): the learned weights are the package's
weights file, in the format experiments/segmentation/train_merge.py writes; the over-segmentation's settings
are an OverSegmentation's, named so where MergeWeights is given them; records keep both in one
flat "merge" entry."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import re
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest

from torchakvf import merge_options as mo
from torchakvf.errors import ParameterError, TorchAKVFError
from torchakvf.options import SegmentOptions
from torchakvf.parts.merge import FIELD_OF_TERM
from torchakvf.parts.merge_terms import TERM_NAMES

PACKAGE_FILE = files("torchakvf") / "parts" / "merge_weights.json"


def train_merge():
    """experiments/segmentation/train_merge.py as a module (its fit needs the captures; its writer not)."""
    path = Path(__file__).resolve().parents[1] / "experiments" / "segmentation" / "train_merge.py"
    spec = importlib.util.spec_from_file_location("train_merge", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_default_weights_are_the_package_file():
    """MergeWeights() reads every learned field from the package file, and the file sets exactly
    the fields a fit makes: the pair terms' weights, size, the intercept and the Rand exponent."""
    values = json.loads(PACKAGE_FILE.read_text())["merge_weights"]
    assert set(values) == set(mo.LEARNED_FIELDS) == set(FIELD_OF_TERM.values()) | {"size", "intercept", "rand_gamma"}
    assert dict(mo.LEARNED_WEIGHTS) == mo.read_merge_weights(PACKAGE_FILE) == values
    default = mo.MergeWeights()
    assert {name: getattr(default, name) for name in mo.LEARNED_FIELDS} == values
    assert {f.name for f in dataclasses.fields(mo.MergeWeights)} - set(mo.LEARNED_FIELDS) == {"crease_angle",
                                                                                           "sheet_flatness"}
    with pytest.raises(TypeError):
        mo.LEARNED_WEIGHTS["symmetry"] = 0.0     # the defaults are read once and cannot be changed


def test_training_script_writes_the_package_file():
    """The script's writer, given the package file's weights as a fit returns them (the cost
    weights by TERM_NAMES, the intercept, γ), writes the package file byte for byte; another fit
    writes a file that reads back as MergeWeights (4 significant digits)."""
    tm = train_merge()
    record = json.loads(PACKAGE_FILE.read_text())
    values = record["merge_weights"]
    w = np.array([values[FIELD_OF_TERM[name]] for name in TERM_NAMES])
    # "300 PSB meshes of 15 labelled categories and 150 procedural shapes of 15 families (corpus share 0.5)"
    numbers = re.findall(r"[0-9.]+", record["trained_on"])
    counts = int(numbers[0]), int(numbers[1]), int(numbers[2]), int(numbers[3]), float(numbers[4])
    assert tm.trained_on(*counts) == record["trained_on"]
    got = tm.weights_record(w, values["intercept"], values["rand_gamma"], tm.trained_on(*counts))
    assert got == record
    assert tm.write_weights(got, Path("/dev/null")) + "\n" == PACKAGE_FILE.read_text()
    other = tm.weights_record(w * 1.000123 + 1e-5, 2.7182818, 0.25, tm.trained_on(10, 2, 30, 3, 0.25))
    assert other["merge_weights"]["intercept"] == 2.718
    assert other["trained_on"] == ("10 PSB meshes of 2 labelled categories and 30 procedural shapes of 3 families "
                                   "(corpus share 0.25)")
    assert tm.PACKAGE_FILE.resolve() == Path(str(PACKAGE_FILE)).resolve()


def test_weights_file_round_trip_and_errors(tmp_path):
    path = tmp_path / "w.json"
    values = dict(mo.LEARNED_WEIGHTS, symmetry=1.5, rand_gamma=0.25)
    path.write_text(json.dumps(mo.merge_weights_record(values, "a test")))
    assert mo.read_merge_weights(path) == values and mo.read_merge_weights(str(path)) == values
    assert mo.MergeWeights(**mo.read_merge_weights(path)).symmetry == 1.5
    with pytest.raises(ParameterError, match="fields must be"):
        mo.merge_weights_record({**values, "ratio": 3.0}, "a test")
    with pytest.raises(ParameterError, match="fields must be"):
        mo.merge_weights_record({k: v for k, v in values.items() if k != "size"}, "a test")
    for text in ("{", '{"weights": {}}', '{"merge_weights": {"symmetry": "x"}}'):
        path.write_text(text)
        with pytest.raises(TorchAKVFError, match=r"w\.json: not a merge weights file"):
            mo.read_merge_weights(path)


def test_over_segmentation_settings_name_their_new_spelling():
    """The over-segmentation's settings given to (or read from) MergeWeights fail with one line
    naming OverSegmentation."""
    with pytest.raises(ParameterError, match=r"^ratio moved to OverSegmentation: "
                                             r"SegmentOptions\(overseg=OverSegmentation\(ratio=2\)\)$"):
        mo.MergeWeights(ratio=2)
    with pytest.raises(ParameterError, match=r"min_k, crease_split moved to OverSegmentation"):
        dataclasses.replace(mo.MergeWeights(), min_k=1, crease_split=None)
    with pytest.raises(ParameterError, match=r"extra_max moved"):
        mo.MergeWeights.hand_set(extra_max=4)
    with pytest.raises(ParameterError, match=r"read SegmentOptions.overseg.crease_rings"):
        mo.MergeWeights().crease_rings
    assert not hasattr(mo.MergeWeights(), "nope") and not hasattr(mo.MergeWeights(), "ratio")
    assert getattr(mo.MergeWeights(), "min_k", None) is None
    assert set(mo.OVERSEG_FIELDS) == {"ratio", "extra_max", "min_k", "crease_split", "crease_rings", "crease_concave",
                                      "unite_fragments", "crease_per_piece"}
    assert not set(mo.OVERSEG_FIELDS) & {f.name for f in dataclasses.fields(mo.MergeWeights)}


def test_records_keep_weights_and_over_segmentation_in_one_merge_entry():
    """SegmentOptions.recorded(): every option but overseg, whose fields are in merge's flat dict
    (MERGE_RECORD_FIELDS: both classes' fields, each once), read from the object that holds it."""
    merge_fields = [f.name for f in dataclasses.fields(mo.MergeWeights)]
    assert sorted(mo.MERGE_RECORD_FIELDS) == sorted(merge_fields + list(mo.OVERSEG_FIELDS))
    opts = SegmentOptions(merge=mo.MergeWeights(concavity=8.0), overseg=mo.OverSegmentation(min_k=3, crease_split=None))
    rec = opts.recorded()
    assert list(rec) == [name for name in SegmentOptions.names() if name != "overseg"]
    assert list(rec["merge"]) == list(mo.MERGE_RECORD_FIELDS)
    assert rec["merge"] == {**dataclasses.asdict(opts.merge), **dataclasses.asdict(opts.overseg)}
    assert rec["merge"]["min_k"] == 3 and rec["merge"]["crease_split"] is None and rec["merge"]["concavity"] == 8.0
    assert SegmentOptions().recorded() != rec and SegmentOptions(overseg=mo.OverSegmentation(min_k=3)).recorded() != \
        SegmentOptions().recorded()


def test_concave_choice_defaults_and_checks():
    """The segmentation's second merge: the hand-set cost, ratio 3, floor 0.05; weights that
    read rays or part sums (not computed for it), a ratio below 1 and a floor outside [0, 1)
    are one-line ParameterErrors; SegmentOptions takes None (off) or a ConcaveChoice."""
    choice = SegmentOptions().merge_choice
    assert choice == mo.ConcaveChoice(weights=mo.MergeWeights.hand_set(), ratio=3.0, floor=0.05)
    with pytest.raises(ParameterError, match="may not read thickness"):
        mo.ConcaveChoice(weights=mo.MergeWeights.hand_set(thickness=1.0))
    with pytest.raises(ParameterError, match="ratio"):
        mo.ConcaveChoice(ratio=0.5)
    with pytest.raises(ParameterError, match="floor"):
        mo.ConcaveChoice(floor=1.0)
    with pytest.raises(ParameterError, match="merge_choice"):
        SegmentOptions(merge_choice="hand-set")
    assert SegmentOptions(merge_choice=None).merge_choice is None


def test_concave_choice_is_recorded():
    """Records keep the choice as a plain dict (JSON-able), None where off; two options that
    differ only there record differently."""
    on, off = SegmentOptions().recorded(), SegmentOptions(merge_choice=None).recorded()
    assert off["merge_choice"] is None
    assert on["merge_choice"]["ratio"] == 3.0 and on["merge_choice"]["floor"] == 0.05
    assert on["merge_choice"]["weights"]["concavity"] == 16.0
    assert json.loads(json.dumps(on["merge_choice"])) == on["merge_choice"]
    assert on != off


def test_part_descriptors_segment_without_the_choice():
    """The part columns keep the segmentations they were measured with: no second merge, no
    sheet rule, the learned weights otherwise."""
    from torchakvf.parts.part_descriptors import PART_OPTIONS, PART_OVERSEGMENTATION

    assert PART_OPTIONS.merge_choice is None and PART_OPTIONS.overseg == PART_OVERSEGMENTATION
    assert PART_OPTIONS.merge == mo.MergeWeights(sheet_flatness=None)


def test_sheet_flatness_default_checks_and_record():
    """Both merges default to the sheet rule at 0.9; None turns it off; a value outside (0, 1]
    is a one-line ParameterError; records keep it (None where off)."""
    assert mo.MergeWeights().sheet_flatness == 0.9
    assert SegmentOptions().merge_choice.weights.sheet_flatness == 0.9
    assert mo.MergeWeights(sheet_flatness=None).sheet_flatness is None
    assert mo.MergeWeights(sheet_flatness=1.0).sheet_flatness == 1.0
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ParameterError, match=r"sheet_flatness must be None or in \(0, 1\]"):
            mo.MergeWeights(sheet_flatness=bad)
    assert SegmentOptions().recorded()["merge"]["sheet_flatness"] == 0.9
    off = SegmentOptions(merge=mo.MergeWeights(sheet_flatness=None)).recorded()["merge"]
    assert off["sheet_flatness"] is None and list(off) == list(mo.MERGE_RECORD_FIELDS)
