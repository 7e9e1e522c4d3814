"""The merge method's floor on over-segmentation (MergeWeights.min_k): every k below it is
over-segmented as min_k is, so the k's of a mesh up to min_k share one untangling and one
k-means (kept per (mesh, n, k') across the rounds of a solve), merged down to each k."""
import numpy as np
import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf import options
from torchakvf.parts import cut, field_counts, rounds, segment_each_k
from torchakvf.parts.merge import MergeWeights, oversegment_k


def test_oversegment_k_floor_by_hand():
    # ratio 3, cap k + 16: k < 5 takes the k' of 5 (15); above the floor each k its own
    assert [oversegment_k(k, 3.0, 10 ** 6, 16, 5) for k in (1, 2, 4, 5, 6, 8, 20)] == [15, 15, 15, 15, 18, 24, 36]
    assert [oversegment_k(k, 3.0, 10 ** 6, 16, 1) for k in (1, 2, 5)] == [3, 6, 15]
    assert oversegment_k(2, 3.0, 10, 16, 5) == 10                       # at most the faces
    assert oversegment_k(2, 3.0, 10 ** 6, 4, 5) == 9                     # the cap counts from the floor


def test_field_counts_follow_the_floor(monkeypatch):
    # merge: 3 max(k, min_k), rounded up to a multiple of FIELDS_STEP (8), in [16, 32]
    assert options.FIELDS_STEP == {"paper": 1, "merge": 8}
    assert [field_counts.default_n_fields(k, "merge", 1) for k in (1, 5, 6, 8, 9, 12)] == [16, 16, 24, 24, 32, 32]
    assert field_counts.default_n_fields(2, "merge", 7) == 24 == field_counts.default_n_fields(7, "merge", 1)
    assert field_counts.default_n_fields(12, "merge", 7) == 32
    # min_k None: the default MergeWeights' (8) with method merge, 1 with the paper's 2k
    assert field_counts.default_n_fields(2, "merge") == 24 and field_counts.akvf_count([[2]]) == 24 + options.SPARE_FIELDS
    assert [field_counts.default_n_fields(k, "paper") for k in (2, 8, 9, 11, 17)] == [16, 16, 18, 22, 32]
    assert field_counts.akvf_count([[2, 3]], None, "merge", 1) == 16 + options.SPARE_FIELDS
    monkeypatch.setitem(options.FIELDS_STEP, "merge", 1)
    assert field_counts.default_n_fields(2, "merge", 7) == 21 == field_counts.default_n_fields(7, "merge", 1)


@pytest.mark.parametrize("bad", [0, -1, True, 2.5, None])
def test_min_k_is_checked(bad):
    with pytest.raises(ParameterError, match="min_k"):
        MergeWeights(min_k=bad)


def test_floor_only_when_parts_are_merged():
    assert options.SegmentOptions(merge=MergeWeights(min_k=5)).merge_min_k == 5
    assert options.SegmentOptions(method="paper", merge=MergeWeights(min_k=5)).merge_min_k == 1
    assert options.SegmentOptions(eps=0.1, merge=MergeWeights(min_k=5)).merge_min_k == 1
    assert field_counts.cluster_count(2, 1000, options.SegmentOptions(method="paper", merge=MergeWeights(min_k=5))) == 2


@pytest.fixture(scope="module")
def blobs():
    s = shapes.three_blobs(n_around=20)
    return ta.akvf(ta.Mesh(s.vertices, s.faces), n=20, remedy="smooth")


FAST = dict(seed=0, refine=False, kmeans_restarts=3, untangle_restarts=1)


def _count_kmeans(monkeypatch):
    calls = []
    real = rounds.spherical_kmeans

    def counted(x, mask, k, **kw):
        calls.append(list(k) if not isinstance(k, int) else [k])
        return real(x, mask, k, **kw)
    monkeypatch.setattr(rounds, "spherical_kmeans", counted)
    return calls


def test_ks_below_the_floor_share_one_kmeans_and_equal_each_k_alone(blobs, monkeypatch):
    merge = MergeWeights(min_k=4)
    calls = _count_kmeans(monkeypatch)
    res = segment_each_k(blobs, [[2, 3, 4, 5]], merge=merge, **FAST)
    # k = 2, 3, 4 share (n 16, k' 12); k = 5 has its own k' = 15
    assert calls == [[12], [15]]
    assert {m.params["k_oversegment"] for m in res.meshes[0].values()} == {12, 15}
    assert len({id(r.untangled) for r in res.rounds}) == 1
    for k in (2, 3, 4, 5):
        calls.clear()
        alone = ta.segment(blobs, k=k, merge=merge, **FAST)[0]
        assert len(calls) == 1
        got = res.meshes[0][k]
        assert len(np.unique(got.labels)) == k
        np.testing.assert_array_equal(got.labels, alone.labels)
        assert got.cost == alone.cost
        assert got.params["merge_min_k"] == 4


def test_floor_in_a_batch_equals_each_mesh_alone(monkeypatch):
    ms = [ta.Mesh(s.vertices, s.faces) for s in (shapes.three_blobs(n_around=20), shapes.dumbbell())]
    batch = ta.MeshBatch.from_meshes(ms)
    fields = ta.akvf(batch, n=20, remedy="smooth")
    merge = MergeWeights(min_k=3)
    calls = _count_kmeans(monkeypatch)
    ks = [[2, 3, 4], [3, 2]]
    res = segment_each_k(fields, ks, merge=merge, **FAST)
    # round 0: both new (one call per distinct field count); round 1: both reuse round 0's
    # (k' 9 for k <= 3); round 2: mesh 0's k = 4 only
    assert sorted(k for c in calls for k in c) == [9, 9, 12] and calls[-1] == [12]
    for b, m in enumerate(ms):
        one = ta.akvf(m, n=20, remedy="smooth")
        for k in ks[b]:
            alone = ta.segment(one, k=k, merge=merge, **FAST)[0]
            np.testing.assert_array_equal(res.meshes[b][k].labels, alone.labels)
            assert res.meshes[b][k].cost == pytest.approx(alone.cost, rel=1e-12, abs=1e-12)


def test_reused_clustering_is_the_recomputed_one(blobs):
    """A round served from the kept clustering equals k-means run again on its features."""
    opts = options.SegmentOptions(merge=MergeWeights(min_k=4), **{k: v for k, v in FAST.items() if k != "untangle_restarts"})
    made = list(rounds.segment_rounds(blobs, [[3, 2]], opts))
    unt = made[1].untangled
    from torchakvf.mesh.batch import pad_packed
    xpad, mask = pad_packed(unt.features.double(), blobs.batch.face_ptr)
    again = rounds.spherical_kmeans(xpad, mask, [12], restarts=3, seed=0, max_iter=opts.kmeans_max_iter)
    clean = cut.cut_parts(blobs.batch, blobs, unt, again, 0, 2, opts)
    np.testing.assert_array_equal(made[1].meshes[0].labels, clean.labels)
    assert made[1].meshes[0].cost == clean.cost
    assert torch.equal(torch.as_tensor(made[0].meshes[0].features), torch.as_tensor(clean.features))


def test_segment_options_take_the_api_graphcut_values():
    """evaluate_psb(graphcut=False) and friends pass the API's values into SegmentOptions."""
    from torchakvf.parts.graphcut import GraphCut
    assert options.SegmentOptions(graphcut=False).graphcut is None
    assert options.SegmentOptions(graphcut=None).graphcut is None
    assert options.SegmentOptions(graphcut=True).graphcut == GraphCut()
    assert options.SegmentOptions(graphcut=GraphCut(band=3)).graphcut == GraphCut(band=3)
    with pytest.raises(ParameterError, match="graphcut"):
        options.SegmentOptions(graphcut="yes")
