"""The cut stage's fast paths (issues 12 and 13) give the straightforward computations' answers,
bitwise: group sums by a sparse indicator product against np.add.at, the graph cut's band as bit
sets against sparse-matrix products, the small-piece clean-up against its dict loop, the graph
cut's inputs to gco against the full-size construction, and the merge stages with their shared
per-mesh / per-k arrays against computing them afresh. Each reference is written out here."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from torchakvf import shapes
from torchakvf.mesh.clean import face_areas
from torchakvf.parts import discovery, graphcut as gc
from torchakvf.parts.concavity import crease_weights, dual_edges
from torchakvf.parts.discovery import CONNECTING, remove_small_parts
from torchakvf.parts.grouping import group_sums
from torchakvf.parts.merge import (MergeWeights, boundary_bends, merge_parts, next_merge_cost,
                                   partition_cost, region_graph, unit_rows)
from torchakvf.parts.topology import face_adjacency, labelled_pieces, piece_label_counts, piece_neighbours


def _sphere_labels(level: int, k: int, seed: int):
    """An icosphere's faces cut into k parts by random directions (nearest direction wins)."""
    s = shapes.icosphere(level)
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    rng = np.random.default_rng(seed)
    bary = v[f].mean(1)
    return v, f, np.argmax(bary @ rng.normal(size=(3, k)), axis=1)


# ---------------------------------------------------------------- group sums

def test_group_sums_is_add_at_bitwise():
    rng = np.random.default_rng(0)
    for n, m, groups in ((1, 1, 1), (7, 1, 3), (500, 5, 9), (3000, 32, 40)):
        g = rng.integers(0, groups, n)
        rows = rng.normal(size=(n, m)) * rng.choice([1e-8, 1.0, 1e8], size=(n, 1))
        ref = np.zeros((groups, m))
        np.add.at(ref, g, rows)
        np.testing.assert_array_equal(group_sums(g, rows, groups), ref)
        # and the per-part boolean-mask sums a loop over parts would take
        loop = np.stack([rows[g == p].sum(axis=0) if (g == p).any() else np.zeros(m) for p in range(groups)])
        if m > 1:                      # (one column: numpy sums pairwise, not row by row)
            np.testing.assert_array_equal(group_sums(g, rows, groups), loop)
    assert group_sums(np.zeros(0, dtype=int), np.zeros((0, 3)), 4).shape == (4, 3)
    np.testing.assert_array_equal(group_sums(np.array([2, 2]), np.ones((2, 2)), 3), [[0, 0], [0, 0], [2, 2]])


# ---------------------------------------------------------------- graph-cut band

def _allowed_by_products(labels, pairs, k, band):
    """The band by sparse products with (adjacency + identity), clipped to 1 each ring."""
    n = len(labels)
    ok = labels >= 0
    reach = sp.csr_matrix((np.ones(int(ok.sum())), (np.flatnonzero(ok), labels[ok])), shape=(n, k))
    if band > 0 and len(pairs):
        adj = sp.coo_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]],
                                                       np.r_[pairs[:, 1], pairs[:, 0]])), shape=(n, n))
        step = (adj + sp.identity(n)).tocsr()
        for _ in range(band):
            reach = step @ reach
            reach.data[:] = 1.0
    return reach.toarray() > 0


@pytest.mark.parametrize("k,band", [(2, 0), (2, 1), (7, 3), (20, 6), (64, 2), (65, 4), (150, 6)])
def test_allowed_labels_equals_sparse_products(k, band):
    v, f, labels = _sphere_labels(3, k, seed=k + band)
    pairs = face_adjacency(f)
    np.testing.assert_array_equal(gc.allowed_labels(labels, pairs, k, band),
                                  _allowed_by_products(labels, pairs, k, band))


def test_allowed_labels_on_a_random_graph_with_unlabelled_faces():
    rng = np.random.default_rng(3)
    n, k = 300, 70
    labels = rng.integers(-1, k, n)
    pairs = rng.integers(0, n, size=(500, 2))          # repeated pairs and self-loops too
    for band in (0, 1, 2, 5):
        np.testing.assert_array_equal(gc.allowed_labels(labels, pairs, k, band),
                                      _allowed_by_products(labels, pairs, k, band))
    np.testing.assert_array_equal(gc.allowed_labels(labels, np.zeros((0, 2), dtype=int), k, 3),
                                  _allowed_by_products(labels, np.zeros((0, 2), dtype=int), k, 3))


def _graphcut_inputs_full_size(labels, distances, dual, face_area, opts):
    """What graphcut_labels hands gco, built the straightforward way: the data terms of every
    labelled face, the fixed faces' edges folded in, then the band's rows taken."""
    k = distances.shape[1]
    sites = np.flatnonzero(labels >= 0)
    index = np.full(len(labels), -1, dtype=np.int64)
    index[sites] = np.arange(len(sites))
    pa, pb = index[dual.pairs[:, 0]], index[dual.pairs[:, 1]]
    inside = (pa >= 0) & (pb >= 0)
    pairs = np.stack([pa[inside], pb[inside]], axis=1)
    w = opts.smoothness * gc.edge_weights(dual, opts)[inside]
    area = np.asarray(face_area, dtype=np.float64)[sites]
    d = np.asarray(distances, dtype=np.float64)[sites]
    finite = np.isfinite(d)
    d = np.where(finite, d, 0.0)
    unary = d * (area / max(float(area.mean()), 1e-300))[:, None]
    allowed = _allowed_by_products(labels[sites], pairs, k, opts.band) & finite
    own = labels[sites]
    free = allowed.sum(axis=1) > 1
    fa, fb = free[pairs[:, 0]], free[pairs[:, 1]]
    unary = unary.copy()
    for side, other in ((0, 1), (1, 0)):
        edge = free[pairs[:, side]] & ~free[pairs[:, other]]
        f_free, f_fixed = pairs[edge, side], pairs[edge, other]
        np.add.at(unary, f_free, w[edge][:, None])
        np.add.at(unary, (f_free, own[f_fixed]), -w[edge])
    idx = np.flatnonzero(free)
    local = np.full(len(sites), -1, dtype=np.int64)
    local[idx] = np.arange(len(idx))
    both = fa & fb
    sub_pairs, sub_w, sub_unary = local[pairs[both]], w[both], unary[idx]
    incident = np.bincount(sub_pairs.ravel(), weights=np.r_[sub_w, sub_w], minlength=len(idx))
    big = float(np.abs(sub_unary).max(initial=0.0) + incident.max(initial=0.0)) + 1.0
    return np.where(allowed[idx], sub_unary, big), sub_pairs, sub_w


@pytest.mark.parametrize("seed,k", [(0, 5), (1, 5), (2, 5), (3, 70)])
def test_graphcut_hands_gco_the_full_size_construction(monkeypatch, seed, k):
    v, f, labels = _sphere_labels(3, k, seed)
    labels = labels.copy()
    rng = np.random.default_rng(seed)
    labels[rng.random(len(labels)) < 0.02] = -1                     # a few faces out of the cut
    dual = dual_edges(v, f)
    area = face_areas(v, f)
    dist = rng.random((len(labels), k))
    dist[rng.random(dist.shape) < 0.05] = np.inf
    opts = gc.GraphCut(smoothness=2.0, band=2)
    seen = []

    def record(unary, pairs, weights, cycles, allowed=None):
        seen.append((unary.copy(), pairs.copy(), weights.copy()))
        assert allowed is not None and allowed.shape == unary.shape and (allowed.sum(axis=1) > 1).all()
        return np.argmin(unary, axis=1)                              # any labelling will do here

    monkeypatch.setattr(gc, "potts_expansion", record)
    out = gc.graphcut_labels(labels, dist, dual, area, opts)
    out_cached = gc.graphcut_labels(labels, dist, dual, area, opts, cut_cost=gc.edge_weights(dual, opts))
    np.testing.assert_array_equal(out, out_cached)
    ref = _graphcut_inputs_full_size(labels, dist, dual, area, opts)
    assert len(seen) == 2
    for got in seen:
        for a, b in zip(got, ref):
            np.testing.assert_array_equal(a, b)                      # bitwise
    assert (out[labels < 0] == labels[labels < 0]).all()
    assert 0 < len(ref[0]) < (labels >= 0).sum()                     # a band, not every face


def test_corner_means_rows_are_barycenter_values_rows_and_cut_the_same():
    from torchakvf.parts.boundaries import barycenter_values
    v, f, labels = _sphere_labels(3, 4, seed=8)
    rng = np.random.default_rng(8)
    vdist = rng.random((len(v), 4))
    vdist[rng.random(vdist.shape) < 0.01] = np.inf
    full = barycenter_values(f, vdist)
    cm = gc.CornerMeans(f, vdist)
    assert cm.shape == full.shape
    rows = np.flatnonzero(rng.random(len(f)) < 0.3)
    np.testing.assert_array_equal(cm[rows], full[rows])
    dual, area = dual_edges(v, f), face_areas(v, f)
    opts = gc.GraphCut(band=3)
    np.testing.assert_array_equal(gc.graphcut_labels(labels, cm, dual, area, opts),
                                  gc.graphcut_labels(labels, full, dual, area, opts))


# ---------------------------------------------------------------- small-piece clean-up

def _remove_small_parts_loop(labels, adjacency, face_area, min_fraction, into_connecting):
    """The smallest-first loop over pieces with a dict of neighbour counts."""
    out = labels.copy()
    total = face_area.sum()
    n_pieces, piece = labelled_pieces(out, adjacency)
    area = np.bincount(piece, weights=face_area, minlength=n_pieces)
    neighbours = piece_neighbours(piece, out, adjacency)
    for p in np.argsort(area):
        if area[p] >= min_fraction * total:
            break
        faces = piece == p
        if out[faces][0] == CONNECTING:
            continue
        if into_connecting:
            out[faces] = CONNECTING
            continue
        cand = {lab: c for lab, c in neighbours.get(int(p), {}).items() if lab != CONNECTING}
        if cand:
            out[faces] = max(cand, key=cand.get)
    if into_connecting or min_fraction <= 0:
        return out
    # then, while some piece moves: every small piece left joins the label of the neighbouring
    # pieces that are not small it shares the most edges with (the labels as the pass began)
    moved = True
    while moved:
        moved = False
        n_pieces, piece = labelled_pieces(out, adjacency)
        area = np.bincount(piece, weights=face_area, minlength=n_pieces)
        labels_now = out.copy()
        own = {int(piece[f]): int(labels_now[f]) for f in range(len(out))}
        small = {p for p in range(n_pieces) if area[p] < min_fraction * total and own[p] != CONNECTING}
        counted = np.array([not (piece[a] in small and piece[b] in small) for a, b in adjacency], dtype=bool)
        neighbours = piece_neighbours(piece, labels_now, adjacency[counted])
        for p in sorted(small):
            cand = {lab: c for lab, c in neighbours.get(p, {}).items() if lab != CONNECTING}
            if cand:
                out[piece == p] = max(cand, key=cand.get)
                moved = True
    return out


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("into_connecting", [False, True])
def test_remove_small_parts_equals_the_loop(seed, into_connecting):
    v, f, labels = _sphere_labels(3, 6, seed)
    rng = np.random.default_rng(seed)
    noisy = labels.copy()
    flip = rng.random(len(noisy)) < 0.08                             # islands of one face or a few
    noisy[flip] = rng.integers(-1, 6, int(flip.sum()))
    adjacency = face_adjacency(f)
    area = face_areas(v, f)
    for frac in (0.0, 0.001, 0.01, 0.2, 1.5):
        np.testing.assert_array_equal(remove_small_parts(noisy, adjacency, area, frac, into_connecting),
                                      _remove_small_parts_loop(noisy, adjacency, area, frac, into_connecting))


def test_remove_small_parts_leaves_no_small_piece_beside_a_large_one():
    """A strip: two one-face pieces side by side (labels 7, 8) between two large parts, each
    sharing two edges with the other (listed twice) and one with its large neighbour. The
    first pass swaps their labels, so both are still small; the further passes move each into
    the large part beside it."""
    labels = np.array([1, 1, 1, 1, 7, 8, 2, 2, 2, 2])
    # face 4 shares 2 edges with face 5 (a fan) and 1 with face 3; face 5 likewise with 6
    adjacency = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [4, 5], [5, 6], [6, 7], [7, 8], [8, 9]])
    area = np.ones(10)
    out = remove_small_parts(labels, adjacency, area, 0.15, False)
    np.testing.assert_array_equal(out, _remove_small_parts_loop(labels, adjacency, area, 0.15, False))
    assert set(out.tolist()) == {1, 2} and out[4] == 1 and out[5] == 2
    n, piece = labelled_pieces(out, adjacency)
    assert np.bincount(piece).min() >= 2
    # one pass alone (part discovery's rule) swaps them and stops
    first, _ = discovery._small_pieces_pass(labels, adjacency, area, 1.5, False, False)
    np.testing.assert_array_equal(first[4:6], [8, 7])


def test_remove_small_parts_breaks_ties_as_the_dict_does():
    # A strip of unit faces: a one-face piece between two labels, one shared edge each; the
    # label met first in piece_neighbours' order wins, whichever id is smaller.
    for left, right in ((3, 1), (1, 3)):
        labels = np.array([left, left, left, 7, right, right, right])
        adjacency = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6]])
        area = np.ones(7)
        np.testing.assert_array_equal(remove_small_parts(labels, adjacency, area, 0.2, False),
                                      _remove_small_parts_loop(labels, adjacency, area, 0.2, False))
        adjacency = adjacency[::-1]
        np.testing.assert_array_equal(remove_small_parts(labels, adjacency, area, 0.2, False),
                                      _remove_small_parts_loop(labels, adjacency, area, 0.2, False))


def test_piece_label_counts_are_piece_neighbours():
    v, f, labels = _sphere_labels(3, 8, seed=5)
    labels = labels.copy()
    labels[::17] = CONNECTING
    adjacency = face_adjacency(f)
    _, piece = labelled_pieces(labels, adjacency)
    p, lab, count, first = piece_label_counts(piece, labels, adjacency)
    ref = piece_neighbours(piece, labels, adjacency)
    assert {(int(a), int(b)): int(c) for a, b, c in zip(p, lab, count)} == \
           {(a, b): c for a, d in ref.items() for b, c in d.items()}
    for a, d in ref.items():                                         # dict order = order of first
        mine = [int(b) for b in lab[p == a][np.argsort(first[p == a])]]
        assert mine == list(d)


# ---------------------------------------------------------------- merge stages' shared arrays

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
    v, f, labels = _sphere_labels(3, 9, seed=4)
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
    g1 = region_graph(labels, dual, None, area, weights.crease_angle, unit=unit, bends=bends)
    for name in ("labels", "area", "mean", "length", "concave", "convex"):
        np.testing.assert_array_equal(getattr(g0, name), getattr(g1, name))
    np.testing.assert_array_equal(merge_parts(labels, f, v, feats, area, 4, weights, dual),
                                  merge_parts(labels, f, v, feats, area, 4, weights, dual, unit=unit, bends=bends))
    for k in (2, 4):   # one region graph made beforehand serves every k
        np.testing.assert_array_equal(merge_parts(labels, f, v, feats, area, k, weights, dual),
                                      merge_parts(labels, f, v, feats, area, k, weights, dual, graph=g1))
    assert next_merge_cost(labels, dual, feats, area, weights) == \
        next_merge_cost(labels, dual, feats, area, weights, unit=unit, bends=bends)
    assert partition_cost(labels, feats) == partition_cost(labels, feats, unit=unit)
    every = labels + 1                                               # every face in a part
    assert partition_cost(every, feats) == partition_cost(every, feats, unit=unit)
    assert partition_cost(every, feats) == _partition_cost_plain(every, feats)


def test_segment_rounds_with_caches_kept_across_k_equal_one_k_at_a_time(monkeypatch):
    """cut_parts keeps per-mesh arrays (dual edges, bending sums, cut costs) across the rounds
    of one solve, and the over-segmentation carried to the mesh (boundaries, clean-up, region
    graph) across the k's clustered alike: segmenting at k = 2, 3, 4 in one go (one k-means at
    k' = 3 min_k, one over-segmentation) gives each k's labels and costs as a solve-free run at
    that k alone (fresh caches)."""
    pytest.importorskip("gco")
    import torchakvf as ta
    from torchakvf.options import SegmentOptions
    from torchakvf.parts import cut, rounds
    from torchakvf.parts.rounds import segment_rounds

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


def _generators_loop(labels, features, face_area, energies, n_parts, min_share=0.5):
    """part_generators with a masked sum per part."""
    density = features ** 2 * face_area[:, None]
    total = np.maximum(density.sum(axis=0), 1e-300)
    share = np.stack([density[labels == p].sum(axis=0) for p in range(n_parts)]) / total
    out = [[] for _ in range(n_parts)]
    home = share.argmax(axis=0)
    for i in range(features.shape[1]):
        p = int(home[i])
        if share[p, i] >= min_share:
            out[p].append((i, float(share[p, i]), float(energies[i])))
    return [sorted(g, key=lambda t: t[2]) for g in out]


@pytest.mark.parametrize("n_fields", [1, 2, 16])
def test_part_generators_equal_a_masked_sum_per_part(n_fields):
    from torchakvf.parts.generators import part_generators
    v, f, labels = _sphere_labels(3, 6, seed=n_fields)
    labels = labels.copy()
    labels[::23] = -1                                                # connecting region
    labels[labels == 5] = 9                                          # beyond n_parts: in no part
    rng = np.random.default_rng(n_fields)
    feats = np.abs(rng.normal(size=(len(f), n_fields))) * (labels[:, None] + 2.0)
    area = face_areas(v, f)
    energies = rng.random(n_fields)
    got = part_generators(labels, feats, area, energies, 5, min_share=0.3)
    ref = _generators_loop(labels, feats, area, energies, 5, min_share=0.3)
    assert [[(g.field, g.share, g.energy) for g in part] for part in got] == ref    # bitwise shares
    assert part_generators(labels, feats, area, energies, 0) == []


def test_cached_over_segmentation_serves_only_an_identical_clustering():
    """The over-segmentation cut_parts keeps is reused only for equal features, centers and
    labels and the same boundary options: one label changed, or another boundary rule, makes
    a new one."""
    from torchakvf.options import SegmentOptions
    from torchakvf.parts.cut import OverSegmentation, over_settings, part_floor

    rng = np.random.default_rng(3)
    feats, centers, labels = rng.random((50, 4)), rng.random((3, 4)), rng.integers(0, 3, 50)
    opts = SegmentOptions()
    floor = part_floor(3, opts)
    entry = OverSegmentation(source=(feats.copy(), centers.copy(), labels.copy()),
                              settings=over_settings(opts, floor),
                              mesh=None, vdist=None, feats=None, labels=None, area=None, unit=None)
    assert entry.made_from((feats, centers, labels), opts, floor)
    moved = labels.copy()
    moved[7] = (moved[7] + 1) % 3
    assert not entry.made_from((feats, centers, moved), opts, floor)
    assert not entry.made_from((feats, centers[:2], labels), opts, floor)
    assert not entry.made_from((feats, centers, labels), SegmentOptions(boundary="faces"), floor)
    wider = SegmentOptions(min_part_fraction=0.02)
    assert not entry.made_from((feats, centers, labels), wider, part_floor(3, wider))
    assert not entry.made_from((feats, centers, labels), opts, part_floor(40, opts))


def test_part_floor_is_the_fraction_up_to_a_quarter_of_the_mean_part():
    """min_part_fraction up to k = 25 at the default; beyond, a quarter of 1/k."""
    from torchakvf.options import SegmentOptions
    from torchakvf.parts.cut import part_floor

    opts = SegmentOptions()
    assert [part_floor(k, opts) for k in (1, 8, 25)] == [0.01, 0.01, 0.01]
    assert part_floor(50, opts) == 0.005 and part_floor(100, opts) == 0.0025
    assert part_floor(50, SegmentOptions(min_part_fraction=0.001)) == 0.001
    assert part_floor(3, SegmentOptions(min_part_fraction=0.0)) == 0.0


def test_segment_rounds_drops_an_over_segmentation_no_later_k_shares(monkeypatch):
    """A mesh's over-segmentation (fine-mesh arrays) is kept only while its next k clusters
    alike: after k = 2 (k = 3 next, the same k-means) it stays, after k = 3 (k = 9 next, other
    fields and clusters) and after a mesh's last k it goes."""
    pytest.importorskip("gco")
    import torchakvf as ta
    from torchakvf.options import SegmentOptions
    from torchakvf.parts import cut, rounds
    from torchakvf.parts.rounds import segment_rounds

    s = shapes.three_blobs(n_around=20)
    batch = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name="a"), ta.Mesh(s.vertices, s.faces, name="b")])
    fields = ta.akvf(batch, n=36, remedy="smooth")
    opts = SegmentOptions(refine=False)
    seen, real = [], rounds.cut_parts

    def spy(*a):
        out = real(*a)
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
