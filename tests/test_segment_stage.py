"""The segment stage's bookkeeping (issue 13): untangling once per (mesh, field count), the
rotations of a mesh independent of the meshes beside it, k-means independent of the batch."""
from __future__ import annotations

import importlib

import numpy as np
import pytest
import torch

import torchakvf as ta
from torchakvf.parts.merge import MergeWeights
from torchakvf import shapes
from torchakvf.restarts import best_restart
from torchakvf.cluster import spherical_kmeans
from torchakvf.mesh.batch import pad_packed
from torchakvf import options
from torchakvf.parts import cut, field_counts, rounds

untangle_mod = importlib.import_module("torchakvf.fields.untangle")


@pytest.fixture(scope="module")
def fields():
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in
              (("blobs", shapes.three_blobs(n_around=20)), ("dumbbell", shapes.BUILTIN_SHAPES["dumbbell"]()))]
    return ta.akvf(ta.MeshBatch.from_meshes(meshes), n=24, remedy="smooth")


def test_rotations_of_a_subset_are_the_batch_untangling_bits(fields):
    """orthomax_rotations for one mesh gives the bits untangle gives it in the whole batch
    (each mesh at its own n), and untangled_from_rotations rebuilds untangle's arrays exactly."""
    ns = [16, 18]
    whole = ta.untangle(fields, n=ns, seed=3, restarts=3)
    rots = {}
    for b in (1, 0):
        rots.update(untangle_mod.orthomax_rotations(fields, {b: ns[b]}, seed=3, restarts=3))
    for b in range(2):
        assert torch.equal(rots[b].rotation, whole.rotation[b, :ns[b], :ns[b]].double())
        assert rots[b].score == float(whole.score[b])
        assert rots[b].restart_scores.shape == (4,)
        assert rots[b].score == float(rots[b].restart_scores[best_restart(rots[b].restart_scores[None], largest=True)[0]])
        # the mesh's own edges alone (no padding rows of the batch): the same bits
        e0, e1 = int(fields.batch.edge_ptr[b]), int(fields.batch.edge_ptr[b + 1])
        y = fields.forms[e0:e1, :ns[b]].double() * fields.system.mass[e0:e1].double().sqrt()[:, None]
        own = untangle_mod.orthomax(y[None], 3, 3, 1e-6, 500, torch.float32)
        assert torch.equal(own[0][0], rots[b].rotation)
    again = untangle_mod.untangled_from_rotations(fields, [rots[0], rots[1]])
    for name in ("rotation", "forms", "face_vectors", "features", "energies", "score", "iterations"):
        assert torch.equal(getattr(again, name), getattr(whole, name)), name
    assert again.n_fields == ns


def test_kmeans_of_a_mesh_does_not_depend_on_its_batch(fields):
    """Mesh b clustered in a batch (other k beside it) and alone: the same labels, centers, cost."""
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
    seeds = km._kmeanspp(xn, w, draws, ok)
    labels, cost, _, _ = km._lloyd(xn, w, seeds, 100, torch.float32, ok)
    # (padded centers and rows change the float32 GEMM's rounding, not the fixed points reached)
    torch.testing.assert_close(cost, both.restart_costs, rtol=1e-9, atol=0)
    pick = best_restart(cost, largest=False)
    for b in range(2):
        agree = (labels[b, :, pick[b]][mask[b]] == both.labels[b][mask[b]]).double().mean()
        assert agree >= 0.999, agree


def test_rounds_untangle_each_mesh_once_per_count(fields, monkeypatch):
    """Rounds in which one mesh's field count changes untangle that mesh alone, each (mesh, n)
    once, and give the labels of untangling the whole batch at every round's counts."""
    calls = []
    real = rounds.orthomax_rotations

    def spy(f, ns, **kw):
        calls.append(dict(ns))
        return real(f, ns, **kw)

    monkeypatch.setattr(rounds, "orthomax_rotations", spy)
    # every k its own field count (no floor, no rounding): mesh 0: n = 16, 16, 18, 21 (3k); mesh 1
    # sits out rounds 3, 4
    monkeypatch.setitem(options.FIELDS_STEP, "merge", 1)
    ks = [[2, 3, 6, 7], [2, 3]]
    opts = options.SegmentOptions(seed=0, refine=False, kmeans_restarts=4, untangle_restarts=2,
                                 merge=MergeWeights(min_k=1))
    made = list(rounds.segment_rounds(fields, ks, opts))
    pairs = [(b, n) for c in calls for b, n in c.items()]
    assert len(pairs) == len(set(pairs))                       # no (mesh, n) twice
    assert {b for b, _ in pairs} == {0, 1} and sum(b == 1 for b, _ in pairs) == 1
    assert len({id(r.untangled) for r in made[:2]}) == 1     # equal counts share one object
    monkeypatch.setattr(rounds, "orthomax_rotations", real)
    for rnd in made:
        ns = field_counts.field_counts(fields, rnd.ks, min_k=1)
        unt = ta.untangle(fields, n=ns, seed=0, restarts=2)
        x, mask = pad_packed(unt.features.double(), fields.batch.face_ptr)
        n_faces = (fields.batch.face_ptr[1:] - fields.batch.face_ptr[:-1]).tolist()
        km_ks = [field_counts.cluster_count(rnd.ks[b], n_faces[b], opts) if b in rnd.active else 1 for b in range(2)]
        km = spherical_kmeans(x, mask, km_ks, restarts=4, seed=0, max_iter=options.KMEANS_MAX_ITER)
        for b in rnd.active:
            assert rnd.untangled.n_fields[b] == ns[b]
            ref = cut.cut_parts(fields.batch, fields, unt, km, b, rnd.ks[b], opts)
            np.testing.assert_array_equal(rnd.meshes[b].labels, ref.labels)
            assert rnd.meshes[b].cost == ref.cost


def test_default_field_counts_by_method(fields):
    """The paper's N = 2k; the merge method's 3 max(k, min_k) (it clusters into about 3k) rounded
    up to a multiple of 8; clamped to [16, 32]."""
    assert [field_counts.default_n_fields(k) for k in (2, 8, 11, 20)] == [16, 16, 22, 32]
    assert [field_counts.default_n_fields(k, "merge", 1) for k in (2, 5, 6, 7, 9, 20)] == [16, 16, 24, 24, 32, 32]
    assert MergeWeights().min_k == 8    # the default floor: every k <= 8 takes the 24 fields of k = 8
    assert [field_counts.default_n_fields(k, "merge") for k in (2, 5, 8, 9, 20)] == [24, 24, 24, 32, 32]
    with pytest.raises(ta.errors.ParameterError, match="method"):
        field_counts.default_n_fields(3, "nope")
    assert field_counts.akvf_count([[7]], method="paper") == 16 + options.SPARE_FIELDS
    assert field_counts.akvf_count([[7]]) == 24 + options.SPARE_FIELDS            # the default method: merge
    lam = fields.eigenvalues.detach().cpu()
    for method in ("paper", "merge"):
        n = field_counts.default_n_fields(7, method)
        want = [field_counts.cluster_safe_n(lam[b], n, floor=max(8 if method == "merge" else 7, n // 2)) for b in range(2)]
        assert field_counts.field_counts(fields, 7, method=method) == want
    rnd = next(rounds.segment_rounds(fields, 7, options.SegmentOptions(refine=False, kmeans_restarts=1)))
    assert [int(n) for n in rnd.untangled.n_fields] == field_counts.field_counts(fields, 7)


def test_iteration_caps_are_recorded_options(fields):
    """The k-means iteration cap and the graph cut's expansion cycles change the answer, so they
    are options (validated) and land in each segmentation's params (resume compares them)."""
    from torchakvf.parts.graphcut import GraphCut
    with pytest.raises(ta.errors.ParameterError, match="kmeans_max_iter"):
        options.SegmentOptions(kmeans_max_iter=0)
    with pytest.raises(ta.errors.ParameterError, match="cycles"):
        GraphCut(cycles=0)
    opts = options.SegmentOptions(seed=0, refine=False, kmeans_max_iter=7, graphcut=GraphCut(cycles=3),
                                 kmeans_seeded_restarts=1)
    rnd = next(rounds.segment_rounds(fields, [[3], [3]], opts))
    params = rnd.meshes[0].params
    assert params["kmeans_max_iter"] == 7 and params["graphcut_cycles"] == 3.0
    assert params["kmeans_seeded_restarts"] == 1
    assert "kmeans_max_iter" in options.SegmentOptions.names()


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


def test_best_restart_breaks_round_off_ties_towards_the_first():
    """Values within round-off of the best are a tie, won by the earliest restart; a genuinely
    better later restart still wins; NaN never wins."""
    base = 478.4012129587086
    costs = torch.tensor([[650.66, 637.18, base * (1 + 2e-16), base],        # round-off tie: 2
                          [5.0, 4.0, 4.0 * (1 - 1e-9), 6.0],                  # 1e-9 better: 2
                          [float("nan"), 3.0, 3.0, 2.0],                      # NaN first: 3
                          [1.0, 1.0, 1.0, 1.0]], dtype=torch.float64)
    assert best_restart(costs, largest=False).tolist() == [2, 2, 3, 0]
    scores = torch.tensor([[7.0, 9.0 * (1 - 1e-15), 9.0, 8.0],               # round-off tie: 1
                           [7.0, 9.0 * (1 - 1e-9), 9.0, 8.0],                  # 2 is better: 2
                           [-2.0, -1.0 - 1e-14, -1.0, -3.0]], dtype=torch.float64)  # negative: 1
    assert best_restart(scores, largest=True).tolist() == [1, 2, 1]
    assert best_restart(torch.full((1, 3), float("nan")), largest=True).tolist() == [0]
    inf = float("inf")
    assert best_restart(torch.tensor([[1.0, inf, inf], [2.0, -inf, 2.0]]), largest=True).tolist() == [1, 0]
    assert best_restart(torch.tensor([[inf, -inf, 3.0, -inf]]), largest=False).tolist() == [1]
