"""Command-line arguments shared by the commands (:mod:`torchakvf.pipeline.arguments`): the
merge switches as SegmentOptions changes, and the eval command reading them."""
from __future__ import annotations

from argparse import Namespace

import pytest

from torchakvf.evaluate.commands import _segment_overrides
from torchakvf.merge_options import ConcaveChoice, MergeWeights
from torchakvf.options import SegmentOptions
from torchakvf.pipeline.arguments import merge_overrides


@pytest.mark.parametrize("second, sheet", [("on", "on"), ("off", "on"), ("on", "off"), ("off", "off")])
def test_merge_overrides(second, sheet):
    """Nothing at the defaults; --second-merge off drops the ConcaveChoice; --sheet-rule off
    takes the rule off both merges (the second keeps its hand-set cost, ratio and floor)."""
    given = merge_overrides(Namespace(second_merge=second, sheet_rule=sheet))
    opts = SegmentOptions(**given)
    assert (opts.merge_choice is None) == (second == "off")
    assert opts.merge.sheet_flatness == (None if sheet == "off" else 0.9)
    if second == "on":
        expected = MergeWeights.hand_set(**({"sheet_flatness": None} if sheet == "off" else {}))
        assert opts.merge_choice == ConcaveChoice(weights=expected)
    if second == sheet == "on":
        assert given == {}


def test_eval_reads_the_merge_switches():
    args = Namespace(seed=None, remedy=None, boundary=None, min_part_fraction=None, solver=None, method=None,
                     batched=None, graph_cut="on", second_merge="on", sheet_rule="off")
    given = _segment_overrides(args)
    assert given["merge"] == MergeWeights(sheet_flatness=None)
    assert given["merge_choice"].weights.sheet_flatness is None
