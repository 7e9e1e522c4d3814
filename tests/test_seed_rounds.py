"""Warm-started k-means (issue 13): spherical_kmeans' ``init`` (the last restart seeded from
given centers) and segment_rounds' ``kmeans_seeded_restarts`` (seeds from the mesh's previous
round)."""
from __future__ import annotations

import importlib

import pytest
import torch

import torchakvf as ta
from torchakvf.restarts import ROUND_OFF_TIE, best_restart
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.errors import ParameterError
from torchakvf.options import SegmentOptions
from torchakvf.parts.rounds import previous_centroids, segment_rounds
from torchakvf.parts.merge import MergeWeights

rounds_mod = importlib.import_module("torchakvf.parts.rounds")


def _features(n: int, d: int, groups: int, seed: int) -> torch.Tensor:
    """[n, d] rows around ``groups`` directions, with noise."""
    gen = torch.Generator().manual_seed(seed)
    dirs = torch.randn(groups, d, generator=gen, dtype=torch.float64)
    pick = torch.randint(groups, (n,), generator=gen)
    return dirs[pick] + 0.6 * torch.randn(n, d, generator=gen, dtype=torch.float64)


def _padded(rows: list) -> tuple[torch.Tensor, torch.Tensor]:
    n_max = max(len(r) for r in rows)
    x = torch.zeros(len(rows), n_max, rows[0].shape[1], dtype=torch.float64)
    mask = torch.zeros(len(rows), n_max, dtype=torch.bool)
    for b, r in enumerate(rows):
        x[b, :len(r)], mask[b, :len(r)] = r, True
    return x, mask


def test_seeded_restart_is_deterministic_and_kept_by_cost():
    x, mask = _padded([_features(400, 6, 7, seed=1)])
    prev = spherical_kmeans(x, mask, 4, restarts=3, seed=2, max_iter=15)
    init = [previous_centroids(x[0], mask[0], prev.labels[0], 9)]
    a = spherical_kmeans(x, mask, 9, restarts=3, seed=2, max_iter=15, init=init)
    b = spherical_kmeans(x, mask, 9, restarts=3, seed=2, max_iter=15, init=init)
    assert torch.equal(a.labels, b.labels) and torch.equal(a.cost, b.cost)
    assert a.restart_costs.shape == (1, 3)
    # the kept restart is the lowest-cost one: no worse than the k-means++ restarts beside it
    assert float(a.cost[0]) == float(a.restart_costs[0, best_restart(a.restart_costs, largest=False)[0]])
    assert float(a.cost[0]) <= float(a.restart_costs[0].min()) * (1 + ROUND_OFF_TIE)
    assert float(a.cost[0]) <= float(a.restart_costs[0, :-1].min()) * (1 + ROUND_OFF_TIE)
    # the seeded restart's centers start at the seeds: seeded from a run's own final centers,
    # Lloyd (which never raises the cost) ends no higher than that run
    full = spherical_kmeans(x, mask, 9, restarts=2, seed=5, max_iter=100)
    again = spherical_kmeans(x, mask, 9, restarts=1, seed=7, max_iter=100, init=[full.centers[0]])
    assert float(again.restart_costs[0, 0]) <= float(full.cost[0]) * (1 + 1e-12)


def test_init_none_entries_and_batch_equal_one_at_a_time():
    rows = [_features(300, 5, 6, seed=3), _features(220, 5, 4, seed=4), _features(260, 5, 5, seed=5)]
    ks = [8, 5, 3]
    x, mask = _padded(rows)
    seeds = [torch.randn(3, 5, generator=torch.Generator().manual_seed(9), dtype=torch.float64), None,
             torch.randn(3, 5, generator=torch.Generator().manual_seed(10), dtype=torch.float64)]
    together = spherical_kmeans(x, mask, ks, restarts=3, seed=1, max_iter=15, init=seeds)
    plain = spherical_kmeans(x, mask, ks, restarts=3, seed=1, max_iter=15)
    for b in range(3):
        xb, mb = _padded([rows[b]])
        alone = spherical_kmeans(xb, mb, ks[b], restarts=3, seed=1, max_iter=15, init=[seeds[b]])
        n = len(rows[b])
        assert torch.equal(together.labels[b, :n], alone.labels[0, :n])
        assert torch.equal(together.cost[b], alone.cost[0])
        assert torch.equal(together.restart_costs[b], alone.restart_costs[0])
    # a mesh without seeds is clustered as without init
    assert torch.equal(together.labels[1], plain.labels[1])
    assert torch.equal(together.restart_costs[1], plain.restart_costs[1])


def test_bad_init_is_a_parameter_error():
    x, mask = _padded([_features(100, 4, 3, seed=6)])
    with pytest.raises(ParameterError):
        spherical_kmeans(x, mask, 3, restarts=2, init=[torch.ones(4, 4, dtype=torch.float64)])  # j > k
    with pytest.raises(ParameterError):
        spherical_kmeans(x, mask, 3, restarts=2, init=[torch.ones(2, 5, dtype=torch.float64)])  # wrong d
    with pytest.raises(ParameterError):
        spherical_kmeans(x, mask, 3, restarts=2, init=[None, None])
    with pytest.raises(ParameterError):
        SegmentOptions(kmeans_seeded_restarts=-1)


def test_previous_centroids_keeps_the_heaviest_clusters():
    x = torch.tensor([[1.0, 0], [1, 0], [1, 0], [0, 1], [0, -1], [0, 0]], dtype=torch.float64)
    mask = torch.tensor([True] * 5 + [False])
    labels = torch.tensor([0, 0, 0, 2, 3, -1])
    c = previous_centroids(x, mask, labels, 3)
    assert torch.allclose(c, torch.tensor([[1.0, 0], [0, 1], [0, -1]], dtype=torch.float64))
    c = previous_centroids(x, mask, labels, 1)
    assert torch.allclose(c, torch.tensor([[1.0, 0]], dtype=torch.float64))


@pytest.fixture(scope="module")
def blob_fields():
    s = shapes.three_blobs()
    return ta.akvf(ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)]), n=20, remedy="smooth")


def test_segment_rounds_seed_each_round_from_the_last(blob_fields, monkeypatch):
    calls = []
    inner = rounds_mod.spherical_kmeans

    def recording(*args, **kwargs):
        km = inner(*args, **kwargs)
        calls.append((kwargs.get("restarts"), kwargs.get("init"), km))
        return km

    monkeypatch.setattr(rounds_mod, "spherical_kmeans", recording)
    # every k its own over-segmentation (min_k 1), so that every round clusters
    opts = SegmentOptions(refine=False, kmeans_seeded_restarts=3, graphcut=None, merge=MergeWeights(min_k=1))
    first = [r.meshes[0].labels.copy() for r in segment_rounds(blob_fields, [[2, 3, 4]], opts)]
    assert [c[0] for c in calls] == [opts.kmeans_restarts, 3, 3]
    assert calls[0][1] is None and all(c[1][0] is not None for c in calls[1:])
    for restarts, init, km in calls[1:]:
        assert float(km.cost[0]) == float(km.restart_costs[0, best_restart(km.restart_costs, largest=False)[0]])
    second = [r.meshes[0].labels.copy() for r in segment_rounds(blob_fields, [[2, 3, 4]], opts)]
    assert all((a == b).all() for a, b in zip(first, second))
    # off: no init, kmeans_restarts every round
    calls.clear()
    list(segment_rounds(blob_fields, [[2, 3]], SegmentOptions(refine=False, graphcut=None, kmeans_seeded_restarts=0,
                                                              merge=MergeWeights(min_k=1))))
    assert [(c[0], c[1]) for c in calls] == [(SegmentOptions().kmeans_restarts, None)] * 2
    assert SegmentOptions().kmeans_seeded_restarts == 0   # off by default
