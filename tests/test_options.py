"""SegmentOptions (:mod:`torchakvf.options`): checked on construction, the API's graphcut values,
k-means restarts by method, the merge floor only where parts are merged, overrides by name."""
from __future__ import annotations

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import options, shapes
from torchakvf.errors import ParameterError
from torchakvf.options import MergeWeights, OverSegmentation
from torchakvf.parts import field_counts, rounds


def test_floor_only_when_parts_are_merged():
    five = OverSegmentation(min_k=5)
    assert options.SegmentOptions(overseg=five).merge_min_k == 5
    assert options.SegmentOptions(method="paper", overseg=five).merge_min_k == 1
    assert options.SegmentOptions(eps=0.1, overseg=five).merge_min_k == 1
    assert field_counts.cluster_count(2, 1000, options.SegmentOptions(method="paper", overseg=five)) == 2


def test_segment_options_take_the_api_graphcut_values():
    """evaluate_psb(graphcut=False) and friends pass the API's values into SegmentOptions."""
    from torchakvf.parts.graphcut import GraphCut
    assert options.SegmentOptions(graphcut=False).graphcut is None
    assert options.SegmentOptions(graphcut=None).graphcut is None
    assert options.SegmentOptions(graphcut=True).graphcut == GraphCut()
    assert options.SegmentOptions(graphcut=GraphCut(band=3)).graphcut == GraphCut(band=3)
    with pytest.raises(ParameterError, match="graphcut"):
        options.SegmentOptions(graphcut="yes")


def test_kmeans_restarts_default_by_method(fields, monkeypatch):
    """kmeans_restarts None resolves to the method's default (merge 3, paper 5), an explicit
    count is kept, bad ones are refused, and the int used is what each segmentation records."""
    assert options.KMEANS_RESTARTS_BY_METHOD == {"paper": 5, "merge": 3}
    assert options.SegmentOptions().kmeans_restarts == 3                   # default method: merge
    assert options.SegmentOptions(method="paper").kmeans_restarts == 5
    assert options.SegmentOptions(method="paper", kmeans_restarts=np.int64(2)).kmeans_restarts == 2
    for bad in (0, 2.5, True):
        with pytest.raises(ta.errors.ParameterError, match="kmeans_restarts"):
            options.SegmentOptions(kmeans_restarts=bad)
    used = []
    real = rounds.spherical_kmeans

    def spy(*args, restarts, **kw):
        used.append(restarts)
        return real(*args, restarts=restarts, **kw)

    monkeypatch.setattr(rounds, "spherical_kmeans", spy)
    for method, want in (("merge", 3), ("paper", 5)):
        rnd = next(rounds.segment_rounds(fields, [[3], [3]], options.SegmentOptions(method=method, refine=False)))
        assert used[-1] == want
        rec = rnd.meshes[0].params["kmeans_restarts"]
        assert rec == want and type(rec) is int
    seg = ta.segment(fields, 3, refine=False)                             # segment's default: None
    assert used[-1] == 3 and seg.meshes[0].params["kmeans_restarts"] == 3


def test_replace_and_overrides_by_name():
    """replace() changes the named options and checks them; an unknown name is a ParameterError
    naming the valid ones; kmeans_restarts left to its default follows a new method."""
    base = options.SegmentOptions()
    assert base.replace() is base
    paper = base.replace(method="paper")
    assert paper.method == "paper" and paper.kmeans_restarts == options.KMEANS_RESTARTS_BY_METHOD["paper"]
    assert options.SegmentOptions(kmeans_restarts=4).replace(method="paper").kmeans_restarts == 4
    assert base.replace(seed=3) == options.SegmentOptions(seed=3)
    with pytest.raises(ParameterError, match="unknown segmentation option.*nope.*the options are: eps"):
        base.replace(nope=1)
    with pytest.raises(ParameterError, match="eps must be >= 0"):
        base.replace(eps=-1.0)
    assert options.segment_options(None, seed=2) == options.SegmentOptions(seed=2)
    assert options.segment_options(paper, eps=0.1) == options.SegmentOptions(method="paper", eps=0.1)
    with pytest.raises(ParameterError, match="must be a SegmentOptions"):
        options.segment_options({"seed": 1})
    assert options.SegmentOptions(merge=None).merge == options.MergeWeights()
    assert options.SegmentOptions(overseg=None).overseg == options.OverSegmentation()
    with pytest.raises(ParameterError, match="overseg must be an OverSegmentation"):
        options.SegmentOptions(overseg=MergeWeights())
    assert "_kmeans_restarts_given" not in options.SegmentOptions.names()


def test_segment_takes_options_and_keywords_alike():
    """segment(batch, k, options) with the same options as keywords gives the same labels; an
    unknown keyword is a ParameterError."""
    s = shapes.three_blobs(n_around=16)
    mesh = ta.Mesh(s.vertices, s.faces)
    fast = dict(seed=1, refine=False, graphcut=False, method="paper")
    by_keywords = ta.segment([mesh], k=3, **fast)
    by_options = ta.segment([mesh], k=3, options=ta.SegmentOptions(**fast))
    assert np.array_equal(by_keywords[0].labels, by_options[0].labels)
    with pytest.raises(ParameterError, match="unknown segmentation option"):
        ta.segment([mesh], k=3, restarts=2)
