"""Batched spherical k-means (:mod:`torchakvf.cluster.spherical_kmeans`): a hand case, the
one-mesh CPU Lloyd path against the batched one (to round-off), a mesh's clustering independent of
its batch, each mesh's seeding that of the batch, warm starts from given centers (``init``), and
float32 iterations against float64."""
from __future__ import annotations

import importlib

import pytest
import torch
from helpers.roundoff import EPS64, assert_same_clustering

import torchakvf as ta
from torchakvf.cluster import spherical_kmeans
from torchakvf.cluster.kmeanspp import kmeanspp
from torchakvf.cluster.spherical_kmeans import lloyd
from torchakvf.errors import ParameterError
from torchakvf.mesh.batch import pad_packed
from torchakvf.options import SegmentOptions
from torchakvf.parts.rounds import previous_centroids
from torchakvf.restarts import ROUND_OFF_TIE, best_restart


def test_spherical_kmeans_hand_case():
    # Two tight bundles of directions, one mesh with k=2 and another with k=1, padded together.
    x = torch.tensor([[[1.0, 0.0], [0.9, 0.1], [0.0, 1.0], [0.1, 0.9]],
                      [[1.0, 1.0], [1.0, 0.9], [0.0, 0.0], [0.0, 0.0]]], dtype=torch.float64)
    mask = torch.tensor([[True] * 4, [True, True, False, False]])
    res = spherical_kmeans(x, mask, [2, 1], restarts=5, seed=0)
    lab = res.labels
    assert lab[0, 0] == lab[0, 1] and lab[0, 2] == lab[0, 3] and lab[0, 0] != lab[0, 2]
    assert lab[1, 0] == lab[1, 1] == 0 and (lab[1, 2:] == -1).all()
    # Cost by hand: cos between (1,0) and the normalized mean of (1,0),(0.9,0.1).
    u = torch.nn.functional.normalize(x[0, :2], dim=1)
    c = torch.nn.functional.normalize(u.sum(0), dim=0)
    expected = 2 * (2 - (u @ c).sum())
    assert float(res.cost[0]) == pytest.approx(float(expected), rel=1e-9)


def test_kmeans_one_mesh_lloyd_equals_the_gathered_batch_path():
    """Lloyd on one mesh (every restart live at first: no per-iteration copies) and on a batch
    of two meshes whose restarts settle at other times (the gathered path CUDA takes): the
    same labels, costs, iteration counts and centers, restart by restart."""
    gen = torch.Generator().manual_seed(4)
    x = torch.randn(2, 300, 6, generator=gen, dtype=torch.float64)
    x[1] += 3 * torch.randn(1, 6, generator=gen, dtype=torch.float64)
    x = torch.nn.functional.normalize(x, dim=-1)
    w = torch.rand(2, 300, generator=gen, dtype=torch.float64)
    seeds = x[:, torch.randperm(300, generator=gen)[:5 * 7]].reshape(2, 5, 7, 6)
    # Other kernels (a gathered batch against one mesh's products): the same clustering to
    # round-off (assert_same_clustering)
    both = lloyd(x, w, seeds, 100, torch.float32)
    for b in range(2):
        alone = lloyd(x[b:b + 1], w[b:b + 1], seeds[b:b + 1], 100, torch.float32)
        assert_same_clustering(alone, [t[b:b + 1] for t in both], x[b:b + 1])
    # restart 0 of five is the single-restart run (the same first draws; five restarts side by
    # side are wider products: the same partition, its cost to round-off, N eps64)
    mask = torch.ones(1, 300, dtype=torch.bool)
    five = spherical_kmeans(x[:1], mask, 7, restarts=5, seed=3)
    one = spherical_kmeans(x[:1], mask, 7, restarts=1, seed=3)
    assert float(one.restart_costs[0, 0]) == pytest.approx(float(five.restart_costs[0, 0]), rel=300 * EPS64)


kmeans_mod = importlib.import_module("torchakvf.cluster.spherical_kmeans")


def _kmeans_problem(n_rows: int, d: int, k: int, r: int, seed: int, duplicate: bool = False):
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(1, n_rows, d, generator=gen, dtype=torch.float64)
    x[0, :n_rows // 2] += 2 * torch.randn(d, generator=gen, dtype=torch.float64)
    x = torch.nn.functional.normalize(x, dim=-1)
    w = torch.rand(1, n_rows, generator=gen, dtype=torch.float64)
    seeds = x[:, torch.randperm(n_rows, generator=gen)[:r * k]].reshape(1, r, k, d).clone()
    if duplicate:
        # two equal centers: ties in every similarity row, and one of them is emptied
        seeds[:, :, 1] = seeds[:, :, 0]
    return x, w, seeds


@pytest.mark.parametrize("dtype,max_iter", [(torch.float32, 15), (torch.float32, 100), (torch.float64, 100)])
@pytest.mark.parametrize("n_rows,d,k,r,duplicate", [(300, 6, 7, 5, False), (400, 8, 12, 3, True),
                                                    (200, 5, 3, 1, False), (150, 4, 1, 2, False)])
def test_lloyd_one_mesh_equals_the_batched_path(n_rows, d, k, r, duplicate, dtype, max_iter):
    x, w, seeds = _kmeans_problem(n_rows, d, k, r, seed=k + r, duplicate=duplicate)
    fast = kmeans_mod.lloyd_one_mesh(x, w, seeds, max_iter, dtype)
    ref = kmeans_mod.lloyd_batched(x, w, seeds, max_iter, dtype)
    # two code paths built to make the same products (bitwise on every CPU tried), asserted to
    # round-off: kernels may differ with a buffer's layout
    assert_same_clustering(fast, ref, x)
    # the dispatch: one CPU mesh with every center present takes the one-mesh path (the same
    # call on the same shapes: the same bits)
    for got, want in zip(kmeans_mod.lloyd(x, w, seeds, max_iter, dtype, torch.ones(1, k, dtype=torch.bool)), fast):
        assert torch.equal(got, want)


def test_lloyd_one_mesh_keeps_seed_layout_out_of_the_answer():
    """Seeds handed over as a strided view (as spherical_kmeans slices them) give the bits of
    contiguous seeds (copied into the same layout first: the same calls on the same operands)."""
    x, w, seeds = _kmeans_problem(300, 6, 5, 3, seed=7)
    wide = torch.zeros(1, 3, 9, 6, dtype=torch.float64)
    wide[:, :, :5] = seeds
    fast = kmeans_mod.lloyd_one_mesh(x, w, wide[:, :, :5], 100, torch.float32)
    for got, want in zip(fast, kmeans_mod.lloyd_one_mesh(x, w, seeds.contiguous(), 100, torch.float32)):
        assert torch.equal(got, want)
    assert_same_clustering(fast, kmeans_mod.lloyd_batched(x, w, seeds, 100, torch.float32), x)


def test_spherical_kmeans_equals_the_batched_path(monkeypatch):
    """Two meshes of other k's (each mesh alone through the fast path on CPU) against the
    general path for each mesh."""
    gen = torch.Generator().manual_seed(11)
    x = torch.randn(2, 250, 6, generator=gen, dtype=torch.float64)
    mask = torch.ones(2, 250, dtype=torch.bool)
    mask[1, 200:] = False
    w = torch.rand(2, 250, generator=gen, dtype=torch.float64)
    fast = spherical_kmeans(x, mask, [4, 9], restarts=5, seed=2, weights=w, max_iter=15)
    monkeypatch.setattr(kmeans_mod, "lloyd", kmeans_mod.lloyd_batched)
    ref = spherical_kmeans(x, mask, [4, 9], restarts=5, seed=2, weights=w, max_iter=15)
    # other kernels: the same clustering to round-off (assert_same_clustering), and so the same
    # restart kept (restart costs differ by far more than round-off)
    xn = torch.nn.functional.normalize(x, dim=-1) * mask[..., None]
    as_runs = lambda r: (r.labels[..., None], r.restart_costs, r.iterations[:, None], r.centers[:, None])  # noqa: E731
    assert_same_clustering(as_runs(fast), as_runs(ref), xn, mask)


def test_kmeans_of_a_mesh_does_not_depend_on_its_batch(fields):
    """Mesh b clustered in a batch (other k beside it) and alone: the same labels, centers, cost,
    bitwise by construction (on the CPU each mesh of a batch is seeded and iterated alone on its
    own rows: the same calls on the same shapes)."""
    unt = ta.untangle(fields, n=16, seed=0, restarts=2)
    x, mask = pad_packed(unt.features.double(), fields.batch.face_ptr)
    both = spherical_kmeans(x, mask, [3, 7], restarts=6, seed=1)
    assert both.restart_costs.shape == (2, 6)
    assert torch.equal(both.cost, both.restart_costs[torch.arange(2), best_restart(both.restart_costs, largest=False)])
    for b, k in enumerate((3, 7)):
        alone = spherical_kmeans(x[b:b + 1], mask[b:b + 1], k, restarts=6, seed=1)
        assert torch.equal(alone.labels[0], both.labels[b])
        assert torch.equal(alone.cost[0], both.cost[b])
        assert torch.equal(alone.centers[0, :k], both.centers[b, :k])
        assert bool((both.centers[b, k:] == 0).all())
    # the batched (padded-center) path that runs off CPU gives the same answer as the per-mesh one
    km = importlib.import_module("torchakvf.cluster.spherical_kmeans")
    xn = torch.nn.functional.normalize(x, dim=-1) * mask[..., None]
    w = mask.double()
    ok = torch.arange(7)[None, :] < torch.tensor([3, 7])[:, None]
    draws = torch.zeros(2, 6, 7, dtype=torch.float64)
    for b, k in enumerate((3, 7)):
        draws[b, :, :k] = torch.rand(6, k, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    seeds = kmeanspp(xn, w, draws, ok)
    labels, cost, _, _ = km.lloyd(xn, w, seeds, 100, torch.float32, ok)
    # (padded centers and rows change the float32 GEMM's rounding, not the fixed points reached)
    torch.testing.assert_close(cost, both.restart_costs, rtol=1e-9, atol=0)
    pick = best_restart(cost, largest=False)
    for b in range(2):
        agree = (labels[b, :, pick[b]][mask[b]] == both.labels[b][mask[b]]).double().mean()
        assert agree >= 0.999, agree


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
        # Lloyd runs on the mesh's own rows either way (the same calls); its seeding sees the
        # batch's padding rows (weight 0), which can only move a pick for a uniform draw within
        # round-off (1e-16) of a step of the cumulative weights: the same centers, the same bits
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


def _is_lloyd_fixed_point(x, mask, res, k) -> bool:
    """The centers are the normalized (unit-weight) means of their clusters, and every row is
    assigned to its nearest center, in float64."""
    xn = torch.nn.functional.normalize(x.double(), dim=-1)
    for b in range(x.shape[0]):
        rows, lab, c = xn[b][mask[b]], res.labels[b][mask[b]], res.centers[b, :k].double()
        sums = torch.zeros_like(c).index_add_(0, lab, rows)
        means = torch.nn.functional.normalize(sums, dim=-1)
        if not torch.allclose(means, c, atol=1e-10):
            return False
        if not bool(((rows @ c.T).argmax(dim=1) == lab).all()):
            return False
    return True


def test_kmeans_float32_iterations_give_float64_labels(blobs_and_bent, blobs_and_bent_float64):
    """float32 Lloyd iterations (then float64 to the end) reach a float64 fixed point with the
    float64 path's labels and cost, with any thread count."""
    x, mask = pad_packed(blobs_and_bent_float64.features.double(), blobs_and_bent.batch.face_ptr)
    for k in (3, 9):
        a = spherical_kmeans(x, mask, k, seed=0, restarts=10, iteration_dtype=torch.float64)
        for threads in (None, 1):
            saved = torch.get_num_threads()
            if threads:
                torch.set_num_threads(threads)
            try:
                b = spherical_kmeans(x, mask, k, seed=0, restarts=10, iteration_dtype=torch.float32)
            finally:
                torch.set_num_threads(saved)
            assert b.centers.dtype == torch.float64
            assert _is_lloyd_fixed_point(x, mask, b, k), (k, threads)
            agree = (a.labels == b.labels)[mask].double().mean().item()
            assert agree > 0.99, (k, threads, agree)
            assert torch.allclose(a.cost, b.cost, rtol=1e-4), (k, threads)
