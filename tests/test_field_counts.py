"""The count policy (:mod:`torchakvf.parts.field_counts`): fields per part by method, rounded
up to the step, clamped, moved off degenerate eigenvalue clusters; the AKVFs to solve for."""
from __future__ import annotations

import pytest

import torchakvf as ta
from torchakvf import options
from torchakvf.options import OverSegmentation
from torchakvf.parts import field_counts, rounds
from torchakvf.parts.field_counts import cluster_safe_n


def test_cluster_safe_n():
    lam = [0.0, 1.0, 2.0, 2.0, 2.0, 3.0]
    assert cluster_safe_n(lam, 4) == 2       # 4 would split the triple 2.0 -> step down
    assert cluster_safe_n(lam, 4, floor=4) == 5  # not allowed below 4 -> complete the cluster
    assert cluster_safe_n(lam, 5) == 5


def test_field_counts_follow_the_floor(monkeypatch):
    # merge: 3 max(k, min_k), rounded up to a multiple of FIELDS_STEP (8), in [16, 32]
    assert options.FIELDS_STEP == {"paper": 1, "merge": 8}
    assert [field_counts.default_n_fields(k, "merge", 1) for k in (1, 5, 6, 8, 9, 12)] == [16, 16, 24, 24, 32, 32]
    assert field_counts.default_n_fields(2, "merge", 7) == 24 == field_counts.default_n_fields(7, "merge", 1)
    assert field_counts.default_n_fields(12, "merge", 7) == 32
    # min_k None: the default OverSegmentation's (8) with method merge, 1 with the paper's 2k
    assert (field_counts.default_n_fields(2, "merge") == 24
            and field_counts.akvf_count([[2]]) == 24 + options.SPARE_FIELDS)
    assert [field_counts.default_n_fields(k, "paper") for k in (2, 8, 9, 11, 17)] == [16, 16, 18, 22, 32]
    assert field_counts.akvf_count([[2, 3]], None, "merge", 1) == 16 + options.SPARE_FIELDS
    monkeypatch.setitem(options.FIELDS_STEP, "merge", 1)
    assert field_counts.default_n_fields(2, "merge", 7) == 21 == field_counts.default_n_fields(7, "merge", 1)


def test_default_field_counts_by_method(fields):
    """The paper's N = 2k; the merge method's 3 max(k, min_k) (it clusters into about 3k) rounded
    up to a multiple of 8; clamped to [16, 32]."""
    assert [field_counts.default_n_fields(k) for k in (2, 8, 11, 20)] == [16, 16, 22, 32]
    assert [field_counts.default_n_fields(k, "merge", 1) for k in (2, 5, 6, 7, 9, 20)] == [16, 16, 24, 24, 32, 32]
    assert OverSegmentation().min_k == 8    # the default floor: every k <= 8 takes the 24 fields of k = 8
    assert [field_counts.default_n_fields(k, "merge") for k in (2, 5, 8, 9, 20)] == [24, 24, 24, 32, 32]
    with pytest.raises(ta.errors.ParameterError, match="method"):
        field_counts.default_n_fields(3, "nope")
    assert field_counts.akvf_count([[7]], method="paper") == 16 + options.SPARE_FIELDS
    assert field_counts.akvf_count([[7]]) == 24 + options.SPARE_FIELDS            # the default method: merge
    lam = fields.eigenvalues.detach().cpu()
    for method in ("paper", "merge"):
        n = field_counts.default_n_fields(7, method)
        floor = max(8 if method == "merge" else 7, n // 2)
        want = [field_counts.cluster_safe_n(lam[b], n, floor=floor) for b in range(2)]
        assert field_counts.field_counts(fields, 7, method=method) == want
    rnd = next(rounds.segment_rounds(fields, 7, options.SegmentOptions(refine=False, kmeans_restarts=1)))
    assert [int(n) for n in rnd.untangled.n_fields] == field_counts.field_counts(fields, 7)
