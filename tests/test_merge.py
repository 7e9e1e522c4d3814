"""Part merging (:mod:`torchakvf.parts.merge`): the region graph and merge cost by hand and
against plain loops, adjacency-only merges, the over-segmentation count, shared arrays against
fresh ones, the two failure-mode shapes (table, mug) part for part, the lines-of-sight term
keeping a U's arms off its base, and the sheet rule (a flat part left among the k parts) by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from helpers.partitions import sphere_labels
from helpers.planar_meshes import hinge
from scipy.sparse.csgraph import connected_components

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.evaluate.k_auto import pick_k
from torchakvf.evaluate.metrics import matched_agreement
from torchakvf.mesh.clean import face_areas
from torchakvf.options import OverSegmentation
from torchakvf.parts.concavity import crease_weights, dual_edges
from torchakvf.parts.creases import unit_face_normals
from torchakvf.parts.field_counts import akvf_count
from torchakvf.parts.merge import (
    MergeCache,
    MergeWeights,
    RegionGraph,
    boundary_bends,
    greedy_merge,
    merge_costs,
    merge_parts,
    merged_distances,
    next_merge_cost,
    oversegment_k,
    partition_cost,
    region_graph,
    unit_rows,
)
from torchakvf.parts.topology import face_adjacency


def test_region_graph_of_the_hinge_by_hand():
    v, f = hinge(np.pi / 2)
    g = region_graph(np.array([5, 2]), dual_edges(v, f), np.array([[3.0, 4.0], [0.0, 2.0]]),
                     np.array([0.5, 0.5]))
    np.testing.assert_array_equal(g.labels, [1, 0])               # compacted in label order
    np.testing.assert_allclose(g.area, [0.5, 0.5])
    np.testing.assert_allclose(g.mean, [[0.0, 1.0], [0.6, 0.8]])  # unit feature rows
    np.testing.assert_allclose(g.length, [[0, 1], [1, 0]])
    np.testing.assert_allclose(g.concave, [[0, 0.5], [0.5, 0]])   # 1 x (π/2)/π


def test_merge_cost_and_order_by_hand():
    g = RegionGraph(labels=np.array([0, 1, 2]), area=np.array([1.0, 1.0, 2.0]),
                    mean=np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                    length=np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]], dtype=float),
                    concave=np.array([[0, 1, 0.5], [1, 0, 0], [0.5, 0, 0]], dtype=float))
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, size=1.0, part_size=0.0, convexity=0.0, cut=0.0)
    cost = merge_costs(g, w)
    # (0,1): same features, κ = 1/2 -> 0 + 2 (1/2) + 1/4; (0,2): orthogonal -> 1 + 1 + 1/4.
    np.testing.assert_allclose(cost[0, 1], 1.25)
    np.testing.assert_allclose(cost[0, 2], 2.25)
    assert np.isinf(cost[1, 2]) and np.isinf(cost[2, 1]) and np.isinf(np.diag(cost)).all()
    new_id, history = greedy_merge(g, 1, w)
    # After (0,1) merge: area 2, mean (1,0); its boundary with 2 is length 1, concave 0.5 ->
    # 1 + 2 (0.5) + 1 * min(2, 2) / 4 = 2.5.
    np.testing.assert_allclose(history, [1.25, 2.5])
    np.testing.assert_array_equal(new_id, [0, 0, 0])
    np.testing.assert_array_equal(greedy_merge(g, 2, w)[0], [0, 0, 1])


def test_learned_rand_cost_by_hand():
    """The default's form: s (the weighted terms) read as the log-odds against one part, the
    cost (a_i a_j)^γ tanh((s - intercept) / 2) = (a_i a_j)^γ (1 - 2 p); k auto reads s - intercept."""
    g = RegionGraph(labels=np.array([0, 1, 2]), area=np.array([1.0, 1.0, 2.0]),
                    mean=np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                    length=np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]], dtype=float),
                    concave=np.array([[0, 1, 0.5], [1, 0, 0], [0.5, 0, 0]], dtype=float))
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0, rand_gamma=0.5, intercept=1.5)
    # s(0,1) = 0 + 2 (1/2) = 1, s(0,2) = 1 + 2 (1/2) = 2; area shares 1/4, 1/4, 1/2
    p01, p02 = 1 / (1 + np.exp(-(1.5 - 1.0))), 1 / (1 + np.exp(-(1.5 - 2.0)))
    cost = merge_costs(g, w)
    np.testing.assert_allclose(cost[0, 1], (1 / 16) ** 0.5 * (1 - 2 * p01))
    np.testing.assert_allclose(cost[0, 2], (1 / 8) ** 0.5 * (1 - 2 * p02))
    assert cost[0, 1] < 0 < cost[0, 2]                 # likely one part: merging it gains
    np.testing.assert_array_equal(greedy_merge(g, 2, w)[0], [0, 0, 1])
    # k auto: the least log-odds against one part among the merged parts' pairs
    v, f = hinge(np.pi / 2)
    # orthogonal features across a right-angle valley: s = 1 + 2 (1/2) = 2, minus 1.5
    assert next_merge_cost(np.array([0, 1]), dual_edges(v, f), np.eye(2), np.ones(2), w) == pytest.approx(0.5)


def test_same_seed_same_labels_with_the_learned_default():
    s = shapes.table()
    mesh = ta.Mesh(s.vertices, s.faces)
    a = ta.segment(mesh, k=5, seed=3)[0].labels
    b = ta.segment(mesh, k=5, seed=3)[0].labels
    np.testing.assert_array_equal(a, b)


def test_convexity_boundary_share_and_part_size_terms_by_hand():
    g = RegionGraph(labels=np.array([0, 1, 2]), area=np.array([1.0, 1.0, 2.0]),
                    mean=np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                    length=np.array([[0, 2, 1], [2, 0, 0], [1, 0, 0]], dtype=float),
                    concave=np.array([[0, 1, 0.5], [1, 0, 0], [0.5, 0, 0]], dtype=float),
                    convex=np.array([[0, 0.4, 0], [0.4, 0, 0], [0, 0, 0]], dtype=float))
    w = MergeWeights.hand_set(symmetry=0.0, concavity=0.0, convexity=1.0, cut=1.0, part_size=1.0)
    # perimeters 3, 2, 1. (0,1): convex 0.4/2 + (1 - 2/min(3,2)) + k min(1,1)/4;
    # (0,2): 0 + (1 - 1/min(3,1)) + k min(1,2)/4.
    cost = merge_costs(g, w, k=2)
    np.testing.assert_allclose([cost[0, 1], cost[0, 2]], [0.2 + 0 + 0.5, 0 + 0 + 0.5])
    new_id, history = greedy_merge(g, 2, w)
    np.testing.assert_array_equal(new_id, [0, 1, 0])
    np.testing.assert_allclose(history, [0.5])
    # k = 1: (0,2) at 1/4 first; then part {0,2} (area 3, perimeter 2) with 1: 0.2 + 0 + 1/4.
    np.testing.assert_allclose(greedy_merge(g, 1, w)[1], [0.25, 0.45])


def _adjacent_label_pairs(labels, faces):
    adj = face_adjacency(faces)
    a, b = labels[adj[:, 0]], labels[adj[:, 1]]
    return {(int(x), int(y)) for x, y in zip(a, b) if x != y}


# the symmetry, concavity and size terms alone
_THREE_TERMS = dict(symmetry=1.0, concavity=1.0, size=1.0, part_size=0.0, convexity=0.0, cut=0.0)


@pytest.mark.parametrize("k,weights", [(1, MergeWeights.hand_set(**_THREE_TERMS)),
                                       (2, MergeWeights.hand_set(**_THREE_TERMS)),
                                       (4, MergeWeights.hand_set(**_THREE_TERMS)),
                                       (3, MergeWeights.hand_set(convexity=2.0, cut=1.0, part_size=0.3,
                                                        crease_angle=0.5)),
                                       (3, MergeWeights()), (2, MergeWeights(crease_angle=0.5))])
def test_merging_only_joins_adjacent_parts(k, weights):
    s = shapes.icosphere(3)
    rng = np.random.default_rng(0)
    # 12 parts: faces by nearest of 12 random directions (connected caps), features random
    # per part, so the merge order is not just geometric.
    centers = rng.normal(size=(12, 3))
    bary = s.vertices[s.faces].mean(1)
    labels = np.argmax(bary @ centers.T, axis=1)
    feats = np.abs(rng.normal(size=(12, 6)))[labels] + 0.01 * rng.random((len(labels), 6))
    out = merge_parts(labels, s.faces, s.vertices, feats, face_areas(s.vertices, s.faces), k, weights)
    assert len(np.unique(out)) == k
    # Every merged part is a union of old parts connected in the old region graph.
    old_adj = _adjacent_label_pairs(labels, s.faces)
    for p in np.unique(out):
        members = np.unique(labels[out == p])
        idx = {m: i for i, m in enumerate(members)}
        edges = [(idx[x], idx[y]) for x, y in old_adj if x in idx and y in idx]
        graph = sp.coo_matrix((np.ones(len(edges)), tuple(np.array(edges).T)) if edges else
                              ([], ([], [])), shape=(len(members),) * 2)
        assert connected_components(graph, directed=False)[0] == 1
    # An old part is never split.
    for lab in np.unique(labels):
        assert len(np.unique(out[labels == lab])) == 1


def test_disconnected_parts_are_never_merged():
    s = shapes.torus_chain(n=3, n_major=36)
    feats = np.ones((len(s.faces), 4))   # identical features: only adjacency stops a merge
    out = merge_parts(s.part_labels, s.faces, s.vertices, feats, face_areas(s.vertices, s.faces), 1)
    assert matched_agreement(out, s.part_labels) == 1.0


def test_merged_distances_take_the_least_over_united_parts():
    d = np.array([[0.1, 0.5, 0.9], [0.7, 0.2, 0.4]])
    before, after = np.array([0, 1, 2, 2]), np.array([0, 0, 1, 1])
    np.testing.assert_allclose(merged_distances(d, before, after), [[0.1, 0.9], [0.2, 0.4]])


def test_merged_distances_of_crease_pieces_meet_on_their_crease():
    # two faces sharing the edge 1-2; one center cut by a crease into two pieces, which the
    # merge put in different parts: off its patch a piece is one farther, on the shared edge
    # (both patches) the two parts tie
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    d = np.array([[0.3], [0.2], [0.1], [0.4]])
    got = merged_distances(d, np.array([0, 0]), np.array([0, 1]), faces=faces, patches=np.array([0, 1]))
    np.testing.assert_allclose(got, [[0.3, 1.3], [0.2, 0.2], [0.1, 0.1], [1.4, 0.4]])
    # without patches the two parts cannot be told apart
    np.testing.assert_allclose(merged_distances(d, np.array([0, 0]), np.array([0, 1])), np.c_[d[:, 0], d[:, 0]])


def test_oversegment_k_and_parameter_errors():
    assert oversegment_k(5, 2.0, 10 ** 6) == 10 and oversegment_k(3, 1.5, 10 ** 6) == 5
    assert oversegment_k(4, 3.0, 7) == 7 and oversegment_k(4, 1.0, 100) == 4
    # the cap on clusters beyond k: 3 x 60 = 180 capped at 60 + 8; below the cap, ceil(3k)
    assert oversegment_k(60, 3.0, 10 ** 6, 8) == 68 and oversegment_k(2, 3.0, 10 ** 6, 8) == 6
    assert oversegment_k(60, 3.0, 10 ** 6, 0) == 60 and oversegment_k(60, 3.0, 65, 8) == 65
    for bad in (-1, 2.5, True):
        with pytest.raises(ParameterError, match="extra_max"):
            OverSegmentation(extra_max=bad)
    with pytest.raises(ParameterError):
        MergeWeights(concavity=-1.0)
    with pytest.raises(ParameterError, match="ratio must be >= 1"):
        OverSegmentation(ratio=0.5)
    for bad in (0.0, math.pi, -0.3):
        with pytest.raises(ParameterError, match="crease_split"):
            OverSegmentation(crease_split=bad)
    with pytest.raises(ParameterError, match="crease_rings"):
        OverSegmentation(crease_rings=0)
    with pytest.raises(ParameterError, match="crease_concave"):
        OverSegmentation(crease_concave=1)
    with pytest.raises(ParameterError, match="unite_fragments"):
        OverSegmentation(unite_fragments=None)
    with pytest.raises(ParameterError, match="crease_per_piece"):
        OverSegmentation(crease_per_piece=1)
    s = shapes.table()
    with pytest.raises(ParameterError, match="method"):
        ta.segment(ta.Mesh(s.vertices, s.faces), k=5, method="nope")


def test_table_and_mug_shapes_are_closed_and_labelled():
    for s, parts in ((shapes.table(), 5), (shapes.mug(), 2)):
        assert s.n_parts == parts and set(np.unique(s.part_labels)) == set(range(parts))
        # closed, manifold, consistently oriented: every edge in exactly two faces, opposite ways
        directed = np.concatenate([s.faces[:, [0, 1]], s.faces[:, [1, 2]], s.faces[:, [2, 0]]])
        assert len({tuple(e) for e in directed.tolist()}) == len(directed)
        assert {tuple(e) for e in directed.tolist()} == {tuple(e) for e in directed[:, ::-1].tolist()}
        assert face_areas(s.vertices, s.faces).min() > 0


@pytest.fixture(scope="module")
def failure_shapes():
    out = {}
    for s in (shapes.table(), shapes.mug()):
        m = ta.Mesh(s.vertices, s.faces, name=s.name)
        # the AKVFs segment solves for itself: the merge method's default fields of k plus spare
        n = akvf_count([[s.n_parts]], None, "merge", OverSegmentation().min_k)
        out[s.name] = (s, ta.akvf(m, n=n, remedy="smooth"))
    return out


@pytest.mark.parametrize("name", ["table", "mug"])
def test_failure_shapes_come_out_part_for_part(failure_shapes, name):
    s, fields = failure_shapes[name]
    seg = ta.segment(fields, k=s.n_parts, seed=0, method="merge", refine=False)[0]
    agree = matched_agreement(seg.labels, s.part_labels, face_areas(s.vertices, s.faces))
    assert agree >= 0.98, f"{name}: area agreement {agree:.4f} after merging"
    assert seg.params["method"] == "merge" and seg.params["k_oversegment"] > s.n_parts
    # Same seed, same labels.
    again = ta.segment(fields, k=s.n_parts, seed=0, method="merge", refine=False)[0]
    np.testing.assert_array_equal(seg.labels, again.labels)


def test_partition_cost_by_hand():
    # Part 0: rows (1,0) and (0,1) -> center (1,1)/√2, cost 2 (1 - 1/√2); part 1: one row, cost 0.
    feats = np.array([[2.0, 0.0], [0.0, 3.0], [1.0, 1.0]])
    np.testing.assert_allclose(partition_cost(np.array([4, 4, 7]), feats), 2 * (1 - 1 / np.sqrt(2)))
    # One part of identical directions costs nothing.
    assert partition_cost(np.zeros(3, dtype=int), np.ones((3, 2))) == pytest.approx(0.0, abs=1e-12)


def test_next_merge_cost_and_the_merge_rule_of_k_auto():
    v, f = hinge(np.pi / 2)
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, part_size=0.0, convexity=0.0, cut=0.0)
    # orthogonal features (1 - cos = 1) across a right-angle valley (κ = 1/2): 1 + 2 (1/2)
    assert next_merge_cost(np.array([0, 1]), dual_edges(v, f), np.eye(2), np.ones(2), w) == pytest.approx(2.0)
    assert next_merge_cost(np.array([0, 0]), dual_edges(v, f), np.eye(2), np.ones(2), w) == np.inf
    ks, nxt = [2, 3, 4, 5, 6], [5.0, 3.0, 0.5, 2.0, 0.1]
    # descending from 6: 0.1 cheap -> 5 (2.0 > τ = 1) stops there
    assert pick_k(ks, np.ones(5), "merge", next_costs=nxt, tau=1.0) == 5
    assert pick_k(ks, np.ones(5), "merge", next_costs=nxt, tau=2.5) == 3
    assert pick_k(ks, np.ones(5), "merge", next_costs=nxt, tau=10.0) == 2
    with pytest.raises(ParameterError, match="next-merge"):
        pick_k(ks, np.ones(5), "merge")


def test_greedy_merge_round_off_tie_goes_to_the_first_pair():
    """Two candidate pairs equal but for the last bits of their cost (as a symmetric shape's
    mirrored pairs are, their products summed in another order on another BLAS): the first
    pair in row-major order is merged, not the one the rounding made cheaper."""
    a = 0.5
    mean = np.array([[1.0, 0.0], [np.cos(a), np.sin(a)], [np.cos(a - 3e-15), np.sin(a - 3e-15)]])
    g = RegionGraph(labels=np.array([0, 1, 2]), area=np.ones(3), mean=mean,
                    length=np.array([[0, 1, 1], [1, 0, 0], [1, 0, 0]], dtype=float),
                    concave=np.zeros((3, 3)))
    w = MergeWeights.hand_set(symmetry=1.0, concavity=0.0, size=0.0, part_size=0.0, convexity=0.0, cut=0.0)
    cost = merge_costs(g, w)
    # (0, 2) is cheaper by round-off only: the tie the rule is for
    assert cost[0, 2] < cost[0, 1] and cost[0, 1] - cost[0, 2] < 1e-12 * cost[0, 1]
    new_id, history = greedy_merge(g, 2, w)
    np.testing.assert_array_equal(new_id, [0, 0, 1])
    assert history == [float(cost[0, 1])]


def test_oversegment_k_floor_by_hand():
    # ratio 3, cap k + 16: k < 5 takes the k' of 5 (15); above the floor each k its own
    assert [oversegment_k(k, 3.0, 10 ** 6, 16, 5) for k in (1, 2, 4, 5, 6, 8, 20)] == [15, 15, 15, 15, 18, 24, 36]
    assert [oversegment_k(k, 3.0, 10 ** 6, 16, 1) for k in (1, 2, 5)] == [3, 6, 15]
    assert oversegment_k(2, 3.0, 10, 16, 5) == 10                       # at most the faces
    assert oversegment_k(2, 3.0, 10 ** 6, 4, 5) == 9                     # the cap counts from the floor


@pytest.mark.parametrize("bad", [0, -1, True, 2.5, None])
def test_min_k_is_checked(bad):
    with pytest.raises(ParameterError, match="min_k"):
        OverSegmentation(min_k=bad)


def test_region_graph_equals_a_plain_loop_over_the_dual_edges():
    s = shapes.icosphere(2)
    rng = np.random.default_rng(1)
    bary = s.vertices[s.faces].mean(1)
    labels = np.argmax(bary @ rng.normal(size=(6, 3)).T, axis=1) * 2     # ids 0, 2, ..., 10
    labels[:5] = -1
    feats = rng.normal(size=(len(labels), 4))
    area = face_areas(s.vertices, s.faces)
    dual = dual_edges(s.vertices, s.faces)
    g = region_graph(labels, dual, feats, area, crease_angle=1.0)
    ids = sorted(set(labels[labels >= 0].tolist()))
    K = len(ids)
    area_ref, mean_ref = np.zeros(K), np.zeros((K, 4))
    for f, lab in enumerate(labels):
        if lab >= 0:
            p = ids.index(lab)
            area_ref[p] += area[f]
            mean_ref[p] += area[f] * feats[f] / np.linalg.norm(feats[f])
    length, concave, convex = (np.zeros((K, K)) for _ in range(3))
    cav, cvx = crease_weights(dual.dihedral, 1.0)
    for e, (a, b) in enumerate(dual.pairs):
        if labels[a] >= 0 and labels[b] >= 0 and labels[a] != labels[b]:
            i, j = ids.index(labels[a]), ids.index(labels[b])
            for mat, val in ((length, 1.0), (concave, cav[e]), (convex, cvx[e])):
                mat[i, j] += dual.length[e] * val
                mat[j, i] += dual.length[e] * val
    np.testing.assert_array_equal(g.labels[labels >= 0], [ids.index(v) for v in labels[labels >= 0]])
    np.testing.assert_allclose(g.area, area_ref, rtol=1e-14)
    np.testing.assert_allclose(g.mean, mean_ref / area_ref[:, None], rtol=1e-12)
    for got, ref in ((g.length, length), (g.concave, concave), (g.convex, convex)):
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)
    # partition_cost from a plain loop too
    unit = feats / np.linalg.norm(feats, axis=1, keepdims=True)
    cost = 0.0
    for lab in ids:
        u = unit[labels == lab]
        c = u.sum(0) / np.linalg.norm(u.sum(0))
        cost += float(np.sum(1 - u @ c))
    np.testing.assert_allclose(partition_cost(labels, feats), cost, rtol=1e-12)


def test_unit_rows_of_a_subset_are_the_subset_of_unit_rows():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(400, 19)) * rng.choice([1e-6, 1.0, 1e6], size=(400, 1))
    x[::13] = 0.0
    keep = rng.random(400) < 0.6
    np.testing.assert_array_equal(unit_rows(x[keep]), unit_rows(x)[keep])


def _partition_cost_plain(labels, feats):
    """Σ_f (1 - cos(x_f, c_p)) with each center the normalized sum of its part's unit rows."""
    norm = np.linalg.norm(feats, axis=1, keepdims=True)
    x = np.divide(feats, norm, out=np.zeros_like(feats), where=norm > 0)
    uniq, inv = np.unique(labels, return_inverse=True)
    centers = np.zeros((len(uniq), feats.shape[1]))
    np.add.at(centers, inv, x)
    centers /= np.linalg.norm(centers, axis=1, keepdims=True)
    return float(np.sum(1.0 - np.einsum("ij,ij->i", x, centers[inv])))


def test_region_graph_and_costs_with_shared_arrays_are_those_computed_afresh():
    v, f, labels = sphere_labels(3, 9, seed=4)
    labels = labels * 3 - 1                                          # ids -1, 2, 5, ...: gaps, one unlabelled
    dual = dual_edges(v, f)
    area = face_areas(v, f)
    rng = np.random.default_rng(4)
    feats = np.abs(rng.normal(size=(len(f), 12)))
    weights = MergeWeights(crease_angle=1.0)
    unit, bends = unit_rows(feats), boundary_bends(dual, weights.crease_angle)
    cav, cvx = crease_weights(dual.dihedral, weights.crease_angle)
    np.testing.assert_array_equal(bends[0], dual.length * cav)
    np.testing.assert_array_equal(bends[1], dual.length * cvx)
    g0 = region_graph(labels, dual, feats, area, weights.crease_angle)
    # with what the weights read (the sheet rule's normals), as MergeCache's graph must be
    g1 = region_graph(labels, dual, None, area, weights.crease_angle, unit=unit, bends=bends,
                      normals=unit_face_normals(v, f))
    for name in ("labels", "area", "mean", "length", "concave", "convex"):
        np.testing.assert_array_equal(getattr(g0, name), getattr(g1, name))
    np.testing.assert_array_equal(merge_parts(labels, f, v, feats, area, 4, weights),
                                  merge_parts(labels, f, v, feats, area, 4, weights,
                                              MergeCache(dual=dual, unit=unit, bends=bends)))
    for k in (2, 4):   # one region graph made beforehand serves every k
        np.testing.assert_array_equal(merge_parts(labels, f, v, feats, area, k, weights, MergeCache(dual=dual)),
                                      merge_parts(labels, f, v, feats, area, k, weights, MergeCache(graph=g1)))
    assert next_merge_cost(labels, dual, feats, area, weights) == \
        next_merge_cost(labels, dual, feats, area, weights, unit=unit, bends=bends)
    assert partition_cost(labels, feats) == partition_cost(labels, feats, unit=unit)
    every = labels + 1                                               # every face in a part
    assert partition_cost(every, feats) == partition_cost(every, feats, unit=unit)
    assert partition_cost(every, feats) == _partition_cost_plain(every, feats)


def test_merge_parts_names_the_cache_for_its_former_arguments():
    """The caches are one MergeCache argument: the dual edges given where the cache goes, or a
    cache by its own keyword, fail with one line naming the new spelling."""
    v, f, labels = sphere_labels(3, 9, seed=4)
    area = face_areas(v, f)
    feats = np.abs(np.random.default_rng(4).normal(size=(len(f), 6)))
    with pytest.raises(ParameterError, match=r"cache=MergeCache\(dual=...\)"):
        merge_parts(labels, f, v, feats, area, 2, None, dual_edges(v, f))
    with pytest.raises(ParameterError, match=r"cache=MergeCache\(bends=..., unit=...\)"):
        merge_parts(labels, f, v, feats, area, 2, unit=unit_rows(feats), bends=None)



def test_lines_of_sight_keep_the_arms_of_a_u_off_its_base():
    """A U of voxels cut into six pieces (the base and each arm in halves): with the sight term
    alone, the halves (convex unions: no segment leaves the solid) merge first and the arms stay
    off the base; without it every cost ties and the first pairs merge (a base half takes an arm).
    The region graph's sight counts are those of SightLines on its compact labels."""
    from helpers.voxel_meshes import voxel_u

    from torchakvf.parts.sightlines import SightLines

    v, f, i, kz = voxel_u()
    pieces = np.where(kz < 2, (i >= 4).astype(int), np.where(i < 4, 2, 4) + (kz >= 5))
    truth = np.where(kz < 2, 0, np.where(i < 4, 1, 2))
    feats = np.ones((len(f), 3))
    area = face_areas(v, f)
    only_sight = MergeWeights.hand_set(symmetry=0.0, concavity=0.0, convexity=0.0, cut=0.0, sight=1.0)
    merged = merge_parts(pieces, f, v, feats, area, 3, only_sight)
    assert matched_agreement(merged, truth) == 1.0
    blind = merge_parts(pieces, f, v, feats, area, 3, MergeWeights.hand_set(symmetry=0.0, concavity=0.0,
                                                                             convexity=0.0, cut=0.0))
    assert matched_agreement(blind, truth) < 0.9
    sight = SightLines(v, f)
    graph = region_graph(pieces, dual_edges(v, f), feats, area, sight=sight)
    seen, lines = sight.counts(graph.labels, graph.n_parts)
    np.testing.assert_array_equal(graph.sums["seen"], seen)
    np.testing.assert_array_equal(graph.sums["lines"], lines)


def _chain_with_a_sheet(flat_part0: float) -> RegionGraph:
    """Three parts in a row, 0 - 1 - 2, the pair (1, 2) the cheaper by the hand-set cost (same
    features, no bending) and (0, 1) the dearer (orthogonal features, a concave boundary);
    part 0's vector area ``flat_part0`` times its area (along z), parts 1 and 2 closed (0)."""
    area = np.array([1.0, 2.0, 2.0])
    vector_area = np.zeros((3, 3))
    vector_area[0, 2] = flat_part0 * area[0]
    return RegionGraph(labels=np.array([0, 1, 2]), area=area,
                       mean=np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 0.0]]),
                       length=np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=float),
                       concave=np.array([[0, 0.5, 0], [0.5, 0, 0], [0, 0, 0]], dtype=float),
                       sums=dict(vector_area=vector_area))


def test_a_sheet_left_among_the_parts_is_merged_first_again():
    """Where the merge by cost leaves a part flatter than ``sheet_flatness`` among the k parts,
    the pieces are merged again with the pairs holding a sheet first: here the cost joins (1, 2)
    and leaves the sheet 0 alone; merged again, the dear pair (0, 1) goes first, and the union
    (vector area (0, 0, 1), area 3: flatness 1/3) is no sheet, so the merge then goes on by
    cost. The history is the returned merge's."""
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0)
    cost = merge_costs(_chain_with_a_sheet(1.0), w)
    assert cost[1, 2] < cost[0, 1]                          # the cost alone merges (1, 2) first
    new_id, history = greedy_merge(_chain_with_a_sheet(1.0), 2, w)
    np.testing.assert_array_equal(new_id, [0, 0, 1])
    assert history == [float(cost[0, 1])]
    off = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0, sheet_flatness=None)
    np.testing.assert_array_equal(greedy_merge(_chain_with_a_sheet(1.0), 2, off)[0], [0, 1, 1])
    # not flatter than the threshold (0.9 against 0.9): the cost decides
    np.testing.assert_array_equal(greedy_merge(_chain_with_a_sheet(0.9), 2, w)[0], [0, 1, 1])
    np.testing.assert_array_equal(greedy_merge(_chain_with_a_sheet(0.95), 2, w)[0], [0, 0, 1])
    # a graph without vector areas has no sheets
    g = _chain_with_a_sheet(1.0)
    g.sums = None
    np.testing.assert_array_equal(greedy_merge(g, 2, w)[0], [0, 1, 1])


def test_a_sheet_the_cost_merges_away_changes_nothing():
    """A sheet among the pieces that the merge by cost joins to a neighbour anyway: the parts
    and the history are those of the rule off (the rule reads the k parts, not the pieces)."""
    g = _chain_with_a_sheet(1.0)
    g.mean = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])     # now (0, 1) is the cheap pair
    g.concave = np.array([[0, 0, 0], [0, 0, 0.5], [0, 0.5, 0]], dtype=float)
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0)
    off = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0, sheet_flatness=None)
    on_id, on_history = greedy_merge(g, 2, w)
    off_id, off_history = greedy_merge(g, 2, off)
    np.testing.assert_array_equal(on_id, [0, 0, 1])
    np.testing.assert_array_equal(on_id, off_id)
    assert on_history == off_history


def test_a_sheet_with_no_neighbour_left_lets_the_others_merge():
    """A sheet on its own component (no adjacent part) does not stop the merge: the others
    merge by cost."""
    g = _chain_with_a_sheet(1.0)
    g.length = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0]], dtype=float)
    g.concave = np.zeros((3, 3))
    w = MergeWeights.hand_set(symmetry=1.0, concavity=2.0, convexity=0.0, cut=0.0)
    np.testing.assert_array_equal(greedy_merge(g, 2, w)[0], [0, 1, 1])


def test_region_graph_vector_areas_of_the_hinge_by_hand():
    """Each face's unit normal times its area, summed by part: the hinge folded by π/2 has
    normals (0, 0, 1) and (0, -1, 0) (the second triangle turned about x), areas 1/2 each, so
    one part of both has the vector area (0, -1/2, 1/2) and flatness √2 / 2."""
    v, f = hinge(np.pi / 2)
    normals = unit_face_normals(v, f)
    np.testing.assert_allclose(normals, [[0, 0, 1], [0, -1, 0]], atol=1e-15)
    apart = region_graph(np.array([0, 1]), dual_edges(v, f), np.ones((2, 2)), np.array([0.5, 0.5]),
                         normals=normals)
    np.testing.assert_allclose(apart.sums["vector_area"], [[0, 0, 0.5], [0, -0.5, 0]], atol=1e-15)
    np.testing.assert_allclose(apart.state().flatness(), [1.0, 1.0])
    one = region_graph(np.array([0, 0]), dual_edges(v, f), np.ones((2, 2)), np.array([0.5, 0.5]),
                       normals=normals)
    np.testing.assert_allclose(one.state().flatness(), [math.sqrt(0.5)])
    assert region_graph(np.array([0, 0]), dual_edges(v, f), np.ones((2, 2)), np.array([0.5, 0.5])).sums is None


def test_closed_surface_is_no_sheet_and_its_halves_are_not_either():
    """A sphere's flatness is 0 (its vector area vanishes); a hemisphere's is the disc over the
    half sphere, 1/2 (within the tessellation's error)."""
    s = shapes.icosphere(4)
    area = face_areas(s.vertices, s.faces)
    half = (s.vertices[s.faces].mean(axis=1)[:, 2] > 0).astype(np.int64)
    g = region_graph(half, dual_edges(s.vertices, s.faces), np.ones((len(s.faces), 2)), area,
                     normals=unit_face_normals(s.vertices, s.faces))
    np.testing.assert_allclose(g.state().flatness(), [0.5, 0.5], atol=0.01)
    whole = region_graph(np.zeros(len(s.faces), dtype=np.int64), dual_edges(s.vertices, s.faces),
                         np.ones((len(s.faces), 2)), area, normals=unit_face_normals(s.vertices, s.faces))
    assert whole.state().flatness()[0] < 1e-12
