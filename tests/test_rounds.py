"""Rounds of a segmentation (:mod:`torchakvf.parts.rounds`): each mesh untangled once per field
count and clustered once per (fields, clusters), k's below the merge floor sharing one k-means,
per-mesh caches kept only while a later k shares them, warm-started rounds, and a mesh's
segmentation in a batch bitwise that of the mesh alone."""
from __future__ import annotations

import importlib

import numpy as np
import pytest
import torch

import torchakvf as ta
from torchakvf import options, shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.mesh.batch import pad_packed
from torchakvf.options import OverSegmentation, SegmentOptions
from torchakvf.parts import cut, field_counts, rounds, segment_each_k
from torchakvf.parts.field_counts import akvf_count
from torchakvf.parts.rounds import previous_centroids, segment_rounds
from torchakvf.restarts import best_restart


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
                                 overseg=OverSegmentation(min_k=1))
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
    overseg = OverSegmentation(ratio=3.0, extra_max=16, min_k=4)
    calls = _count_kmeans(monkeypatch)
    res = segment_each_k(blobs, [[2, 3, 4, 5]], overseg=overseg, **FAST)
    # k = 2, 3, 4 share (n 16, k' 12); k = 5 has its own k' = 15
    assert calls == [[12], [15]]
    assert {m.params["k_oversegment"] for m in res.meshes[0].values()} == {12, 15}
    assert len({id(r.untangled) for r in res.rounds}) == 1
    for k in (2, 3, 4, 5):
        calls.clear()
        alone = ta.segment(blobs, k=k, overseg=overseg, **FAST)[0]
        assert len(calls) == 1
        got = res.meshes[0][k]
        assert len(np.unique(got.labels)) == k
        np.testing.assert_array_equal(got.labels, alone.labels)
        assert got.cost == alone.cost
        assert got.params["merge_min_k"] == 4


def test_rounds_without_extras_cut_the_same_labels_and_costs_without_generators(blobs):
    """extras=False (what the part descriptors and the eval read): at every k the labels and the
    cost of the whole cut (merge and graph cut), without the symmetry generators, the refined
    mesh or the next merge's cost."""
    opts = SegmentOptions(overseg=OverSegmentation(min_k=4), **{**FAST, "refine": True})
    whole = {r.ks[0]: r.meshes[0] for r in segment_rounds(blobs, [[2, 3, 5]], opts)}
    bare = {r.ks[0]: r.meshes[0] for r in segment_rounds(blobs, [[2, 3, 5]], opts, extras=False)}
    for k in (2, 3, 5):
        np.testing.assert_array_equal(bare[k].labels, whole[k].labels)
        assert len(np.unique(bare[k].labels)) == k
        assert bare[k].cost == whole[k].cost and np.isfinite(bare[k].cost)
        assert whole[k].generators and whole[k].refined is not None and "merge_next" in whole[k].params
        assert bare[k].generators == [] and bare[k].refined is None and "merge_next" not in bare[k].params


def test_floor_in_a_batch_equals_each_mesh_alone(monkeypatch):
    ms = [ta.Mesh(s.vertices, s.faces) for s in (shapes.three_blobs(n_around=20), shapes.dumbbell())]
    batch = ta.MeshBatch.from_meshes(ms)
    fields = ta.akvf(batch, n=20, remedy="smooth")
    overseg = OverSegmentation(ratio=3.0, extra_max=16, min_k=3)
    calls = _count_kmeans(monkeypatch)
    ks = [[2, 3, 4], [3, 2]]
    res = segment_each_k(fields, ks, overseg=overseg, **FAST)
    # round 0: both new (one call per distinct field count); round 1: both reuse round 0's
    # (k' 9 for k <= 3); round 2: mesh 0's k = 4 only
    assert sorted(k for c in calls for k in c) == [9, 9, 12] and calls[-1] == [12]
    for b, m in enumerate(ms):
        one = ta.akvf(m, n=20, remedy="smooth")
        for k in ks[b]:
            alone = ta.segment(one, k=k, overseg=overseg, **FAST)[0]
            np.testing.assert_array_equal(res.meshes[b][k].labels, alone.labels)
            assert res.meshes[b][k].cost == pytest.approx(alone.cost, rel=1e-12, abs=1e-12)


def test_reused_clustering_is_the_recomputed_one(blobs):
    """A round served from the kept clustering equals k-means run again on its features."""
    # k' = 3 min_k = 12, the k-means run again below
    opts = options.SegmentOptions(overseg=OverSegmentation(ratio=3.0, extra_max=16, min_k=4),
                                  **{k: v for k, v in FAST.items() if k != "untangle_restarts"})
    made = list(rounds.segment_rounds(blobs, [[3, 2]], opts))
    unt = made[1].untangled
    from torchakvf.mesh.batch import pad_packed
    xpad, mask = pad_packed(unt.features.double(), blobs.batch.face_ptr)
    again = rounds.spherical_kmeans(xpad, mask, [12], restarts=3, seed=0, max_iter=opts.kmeans_max_iter)
    clean = cut.cut_parts(blobs.batch, blobs, unt, again, 0, 2, opts)
    np.testing.assert_array_equal(made[1].meshes[0].labels, clean.labels)
    assert made[1].meshes[0].cost == clean.cost
    assert torch.equal(torch.as_tensor(made[0].meshes[0].features), torch.as_tensor(clean.features))


def test_segment_rounds_with_caches_kept_across_k_equal_one_k_at_a_time(monkeypatch):
    """cut_parts keeps per-mesh arrays (dual edges, bending sums, cut costs) across the rounds
    of one solve, and the over-segmentation carried to the mesh (boundaries, clean-up, region
    graph) across the k's clustered alike: segmenting at k = 2, 3, 4 in one go (one k-means at
    k' = ratio · min_k, one over-segmentation) gives each k's labels and costs as a solve-free run at
    that k alone (fresh caches)."""
    pytest.importorskip("gco")

    s = shapes.three_blobs(n_around=20)
    batch = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name="blobs")])
    fields = ta.akvf(batch, n=24, remedy="smooth")
    opts = SegmentOptions(refine=False)
    made, real = [], cut.over_segmentation
    monkeypatch.setattr(cut, "over_segmentation", lambda *a, **kw: made.append(a[3]) or real(*a, **kw))
    together = {r.ks[0]: r.meshes[0] for r in segment_rounds(fields, [[2, 3, 4]], opts)}
    assert len(made) == 1                       # the three k's shared one over-segmentation
    assert len({seg.params["k_oversegment"] for seg in together.values()}) == 1
    for k in (2, 3, 4):
        alone = next(iter(segment_rounds(fields, [[k]], opts))).meshes[0]
        np.testing.assert_array_equal(together[k].labels, alone.labels)
        assert together[k].cost == alone.cost
        assert together[k].params == alone.params


def test_segment_rounds_drops_an_over_segmentation_no_later_k_shares(monkeypatch):
    """A mesh's over-segmentation (fine-mesh arrays) is kept only while its next k clusters
    alike: after k = 2 (k = 3 next, the same k-means) it stays, after k = 3 (k = 9 next, other
    fields and clusters) and after a mesh's last k it goes."""
    pytest.importorskip("gco")

    s = shapes.three_blobs(n_around=20)
    batch = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name="a"), ta.Mesh(s.vertices, s.faces, name="b")])
    fields = ta.akvf(batch, n=36, remedy="smooth")
    opts = SegmentOptions(refine=False)
    seen, real = [], rounds.cut_parts

    def spy(*a, **kw):
        out = real(*a, **kw)
        seen.append((a[4], a[5], a[7]))          # mesh, k, its cache (as cut_parts leaves it)
        return out

    monkeypatch.setattr(rounds, "cut_parts", spy)
    kept = []
    for rnd in segment_rounds(fields, [[2, 3, 9], [5]], opts):
        kept.append({(b, k): cache.over is not None for b, k, cache in seen})
        seen.clear()
    assert kept == [{(0, 2): True, (1, 5): False}, {(0, 3): False}, {(0, 9): False}]
    round_ks, active, _, km_ks = rounds.round_plan(fields, [[2, 3, 9], [5]], 1, None, opts)
    assert round_ks == [3, rounds.PAD_K] and active == [0]
    assert km_ks[0] == rounds.cluster_count(2, len(s.faces), opts)      # k = 3 clusters as k = 2


def test_mesh_caches_kept_across_calls_make_the_mesh_arrays_once_and_the_same_labels(monkeypatch):
    """Caches passed to two calls (another seed, other k's) make each mesh's crease patches and
    thickness once, and every label and cost is the one a call with fresh caches gives; caches
    for another batch size fail in one line."""
    s = shapes.three_blobs(n_around=20)
    batch = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name="a"), ta.Mesh(s.vertices, s.faces, name="b")])
    fields = ta.akvf(batch, n=24, remedy="smooth")
    opts = SegmentOptions(refine=False)
    made, real = [], cut.crease_patches
    monkeypatch.setattr(cut, "crease_patches", lambda *a, **kw: made.append(1) or real(*a, **kw))
    caches = [cut.MeshCache() for _ in range(2)]
    runs = [(opts, [[3], [2, 4]]), (opts.replace(seed=7), [[5], [3]])]
    kept = [[(r.ks, [m and m.labels for m in r.meshes], [m and m.cost for m in r.meshes])
             for r in segment_rounds(fields, ks, o, mesh_caches=caches)] for o, ks in runs]
    assert len(made) == 2                     # one per mesh, over both calls
    assert all(c.patches and c.sums_inputs is not None and c.over is None for c in caches)
    for (o, ks), got in zip(runs, kept):
        fresh = [(r.ks, [m and m.labels for m in r.meshes], [m and m.cost for m in r.meshes])
                 for r in segment_rounds(fields, ks, o)]
        for (ks_a, lab_a, cost_a), (ks_b, lab_b, cost_b) in zip(got, fresh):
            assert ks_a == ks_b and cost_a == cost_b
            for a, b in zip(lab_a, lab_b):
                assert (a is None and b is None) or np.array_equal(a, b)
    with pytest.raises(ta.ParameterError, match="mesh_caches has 1 entries for a batch of 2"):
        next(iter(segment_rounds(fields, 3, opts, mesh_caches=caches[:1])))


def test_mesh_caches_shared_by_merge_weights_that_read_more_give_each_its_own_labels():
    """Caches made under merge weights that read no thickness, then passed to weights that do,
    give the labels fresh caches give: the thickness is added, not left out."""
    from torchakvf.options import MergeWeights
    from torchakvf.parts.merge import needs_part_sums, needs_thickness

    s = shapes.three_blobs(n_around=20)
    fields = ta.akvf(ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name="a")]), n=24, remedy="smooth")
    thin_free = MergeWeights(thickness=0.0, thin=0.0)
    assert needs_part_sums(thin_free) and not needs_thickness(thin_free) and needs_thickness(MergeWeights())
    caches = [cut.MeshCache()]
    for weights in (thin_free, MergeWeights()):
        opts = SegmentOptions(refine=False, merge=weights)
        shared = next(iter(segment_rounds(fields, 4, opts, mesh_caches=caches))).meshes[0]
        fresh = next(iter(segment_rounds(fields, 4, opts))).meshes[0]
        np.testing.assert_array_equal(shared.labels, fresh.labels)
        assert shared.cost == fresh.cost
    assert caches[0].sums_inputs[1] is not None


rounds_mod = importlib.import_module("torchakvf.parts.rounds")


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
    opts = SegmentOptions(refine=False, kmeans_seeded_restarts=3, graphcut=None, overseg=OverSegmentation(min_k=1))
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
                                                              overseg=OverSegmentation(min_k=1))))
    assert [(c[0], c[1]) for c in calls] == [(SegmentOptions().kmeans_restarts, None)] * 2
    assert SegmentOptions().kmeans_seeded_restarts == 0   # off by default


@pytest.fixture(scope="module")
def solved():
    """Three meshes solved in one batch and each alone, at enough fields for every k below."""
    ms = [ta.Mesh(s.vertices, s.faces, name=s.name)
          for s in (shapes.three_blobs(n_around=20), shapes.dumbbell(), shapes.sphere_with_two_ellipsoids())]
    n = akvf_count([[9]])                       # 32 fields + spare: every k below fits
    batch = ta.akvf(ta.MeshBatch.from_meshes(ms), n=n, remedy="smooth")
    alone = [ta.akvf(m, n=n, remedy="smooth") for m in ms]
    return ms, batch, alone


def test_batched_rounds_equal_each_mesh_alone(solved):
    """A mesh segmented in a batch gets the bits it gets alone (batching must not change
    answers): meshes of one round at different field counts and cluster counts, so the round's
    arrays are padded past each mesh's own. Bitwise by construction: on the CPU every stage
    solves, untangles, clusters and cuts each mesh alone, on its own rows (the same calls on the
    same shapes)."""
    ms, batch, alone = solved
    for b, f in enumerate(alone):   # the batched eigensolve's fields are each mesh's own
        e0, e1 = int(batch.batch.edge_ptr[b]), int(batch.batch.edge_ptr[b + 1])
        assert torch.equal(batch.forms[e0:e1], f.forms)
    # round 0: n 32 / 24 / 24 and k' 27 / 24 / 24; round 1: mesh 1 sits out; round 2: mesh 0 alone
    ks = [[9, 3, 10], [2], [5, 12]]
    opts = SegmentOptions(seed=0, refine=False)
    together = {}
    for rnd in segment_rounds(batch, ks, opts):
        assert rnd.untangled.n == max(int(v) for v in rnd.untangled.n_fields)
        for b in rnd.active:
            together[(b, rnd.ks[b])] = rnd.meshes[b]
    for b, f in enumerate(alone):
        for rnd in segment_rounds(f, [ks[b]], opts):
            one, many = rnd.meshes[0], together[(b, rnd.ks[0])]
            np.testing.assert_array_equal(many.labels, one.labels)
            assert many.cost == one.cost
            assert many.features.shape == one.features.shape
            assert np.array_equal(many.features, one.features)
            assert many.generators == one.generators     # from the untangled fields' energies


def test_cut_jobs_cut_elsewhere_give_the_rounds_own_parts():
    """The solve phase and the cut phase apart (``cut=False``, :func:`mesh_cut_job` pickled as to
    a host process, :func:`cut_mesh_rounds`) give each mesh's parts of ``cut=True`` bit for bit,
    also for a mesh sitting out a round and on a decimated mesh."""
    import pickle

    from torchakvf.mesh import Mesh, MeshBatch
    from torchakvf.parts.rounds import cut_mesh_rounds, mesh_cut_job
    from torchakvf.parts.solve import solve_akvfs

    s = [shapes.dumbbell(n_around=16), shapes.three_blobs(n_around=12)]     # 396, 312 faces
    mb = MeshBatch.from_meshes([Mesh(x.vertices, x.faces, name=str(i)) for i, x in enumerate(s)],
                               coarse_faces=300)
    assert mb.coarse_of(0) is not None                  # the cut maps to the fine mesh
    opts = SegmentOptions(kmeans_restarts=2, untangle_restarts=1, batched=True)
    fields, _ = solve_akvfs(mb, 12, opts)
    ks = [[2, 3], [3]]
    whole = list(segment_rounds(fields, ks, opts, n_fields=8))
    solved = list(segment_rounds(fields, ks, opts, n_fields=8, cut=False))
    assert all(m is None for r in solved for m in r.meshes)
    for b in range(2):
        job = pickle.loads(pickle.dumps(mesh_cut_job(fields, solved, b)))
        cuts = list(cut_mesh_rounds(job, opts))
        assert [k for k, _ in cuts] == ks[b]
        for (k, seg), rnd in zip(cuts, [r for r in whole if b in r.active]):
            ref = rnd.meshes[b]
            assert np.array_equal(seg.labels, ref.labels) and np.array_equal(seg.features, ref.features)
            assert seg.cost == ref.cost and seg.params == ref.params and seg.converged == ref.converged
