"""Tests of the PSB segmentation metrics (torchakvf.evaluate.metrics).

Expected numbers of the small cases are worked out by hand in the comments.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from torchakvf.evaluate.metrics import (
    HammingResult,
    average_radius,
    compare_segmentations,
    consistency_errors,
    cut_discrepancy,
    evaluate_segmentation,
    hamming_distance,
    mesh_face_areas,
    rand_index_error,
)

# The running example: 4 faces.
#   a = [0, 0, 1, 1]   segments {0,1} {2,3}
#   b = [0, 0, 0, 1]   segments {0,1,2} {3}
A4 = np.array([0, 0, 1, 1])
B4 = np.array([0, 0, 0, 1])


# ---------------------------------------------------------------------------------------------
# fixtures: a 3-square strip (hand-checkable geometry) and a sphere
# ---------------------------------------------------------------------------------------------

def strip_mesh():
    """Unit squares s = 0, 1, 2 along x, each split by the diagonal (s,0)-(s+1,1).

    Vertex (x, y) has index x + 4*y. Faces 2s and 2s+1 are square s:
    T1 = (s,0),(s+1,0),(s+1,1) with centroid (s+2/3, 1/3) and
    T2 = (s,0),(s+1,1),(s,1)   with centroid (s+1/3, 2/3); every face has area 1/2.
    """
    vertices = np.array([[x, y, 0.0] for y in (0, 1) for x in range(4)])
    faces = []
    for s in range(3):
        faces.append([s, s + 1, s + 5])
        faces.append([s, s + 5, s + 4])
    return vertices, np.array(faces)


def sphere_mesh(subdivisions=3):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices), np.asarray(m.faces)


def octant_labels(vertices, faces):
    c = vertices[faces].mean(axis=1)
    return (c[:, 0] > 0).astype(int) + 2 * (c[:, 1] > 0.3).astype(int)


# Average radius of the strip, by hand: the area-weighted surface centroid is (1.5, 0.5) by
# symmetry; face-centroid distances to it are sqrt(26)/6, sqrt(50)/6 (squares 0 and 2, twice
# each) and sqrt(2)/6 (square 1, twice); all areas are equal, so the mean is
# (2 sqrt26 + 2 sqrt50 + 2 sqrt2) / 36 = (sqrt26 + sqrt50 + sqrt2) / 18 = 0.754683...
STRIP_RADIUS = (math.sqrt(26) + math.sqrt(50) + math.sqrt(2)) / 18


# ---------------------------------------------------------------------------------------------
# Rand index
# ---------------------------------------------------------------------------------------------

def test_rand_index_hand_case():
    # C(4,2) = 6 pairs: (0,1) same/same ok, (0,2) diff/same X, (0,3) diff/diff ok,
    # (1,2) diff/same X, (1,3) diff/diff ok, (2,3) same/diff X  ->  3 / 6 = 0.5.
    # Formula: sum C(a_i,2) = 1+1, sum C(b_j,2) = 3+0, sum C(n_ij,2) = C(2,2) = 1 -> (2+3-2)/6.
    assert rand_index_error(A4, B4) == pytest.approx(0.5, abs=1e-15)


def test_rand_index_counts_unordered_distinct_pairs():
    # a = [0,0,1], b = [0,1,1]: pairs (0,1) same/diff X, (0,2) diff/diff ok, (1,2) diff/same X.
    # C(3,2) = 3 pairs -> 2/3. (Counting ordered pairs with self-pairs, N^2 = 9, would give 4/9.)
    assert rand_index_error([0, 0, 1], [0, 1, 1]) == pytest.approx(2 / 3, abs=1e-15)


def test_rand_index_identity_and_relabelling():
    rng = np.random.default_rng(1)
    g = rng.integers(0, 7, 500)
    assert rand_index_error(g, g) == 0.0
    # Renaming labels (permutation, gaps, negatives) is not a difference.
    perm = rng.permutation(7)
    assert rand_index_error(g, perm[g] * 13 - 40) == 0.0


def test_rand_index_none_plus_every_is_one():
    # For any g: 1-RI(one, g) = [C(N,2) - S] / C(N,2) and 1-RI(every, g) = S / C(N,2), with
    # S = sum_j C(g_j, 2); the two add up to exactly 1 with C(N,2) pair counting.
    rng = np.random.default_rng(2)
    for n, k in [(2, 1), (7, 3), (301, 5), (1000, 40)]:
        g = rng.integers(0, k, n)
        one = np.zeros(n, dtype=int)
        every = np.arange(n)
        total = rand_index_error(one, g) + rand_index_error(every, g)
        assert total == pytest.approx(1.0, abs=1e-12)


def test_rand_index_every_face_sparse_path():
    # k1*k2 = 90,000 cells > dense limit for 300 faces: exercises the sorted (sparse) table.
    every = np.arange(300)
    assert rand_index_error(every, every[::-1].copy()) == 0.0
    assert consistency_errors(every, every) == (0.0, 0.0)


def test_rand_index_matches_brute_force_and_is_symmetric():
    rng = np.random.default_rng(3)
    for _ in range(30):
        n = int(rng.integers(2, 30))
        a = rng.integers(0, 4, n)
        b = rng.integers(0, 5, n)
        brute = sum((a[i] == a[j]) != (b[i] == b[j])
                    for i, j in itertools.combinations(range(n), 2)) / (n * (n - 1) / 2)
        assert rand_index_error(a, b) == pytest.approx(brute, abs=1e-12)
        assert rand_index_error(a, b) == rand_index_error(b, a)


def test_rand_index_single_face():
    assert rand_index_error([3], [5]) == 0.0


# ---------------------------------------------------------------------------------------------
# Hamming distance
# ---------------------------------------------------------------------------------------------

def test_hamming_hand_case_counts():
    # a = [0,0,1,1], b = [0,0,0,1]: table a0 x b0 = 2; a1 x b0 = 1; a1 x b1 = 1.
    # Rm: best overlap of each b segment: b0 -> 2, b1 -> 1; (4 - 3)/4 = 0.25.
    # Rf: best overlap of each a segment: a0 -> 2, a1 -> 1; (4 - 3)/4 = 0.25.
    r = hamming_distance(A4, B4)
    assert isinstance(r, HammingResult)
    assert r == pytest.approx((0.25, 0.25, 0.25), abs=1e-15)


def test_hamming_asymmetric_and_area_weighted():
    # a = [0,1,2,2] (3 segments), b = [0,0,1,1] (2 segments). Cells (a,b): (0,0)=f0, (1,0)=f1,
    # (2,1)=f2+f3.
    # Counts: Rm = (4 - [max(1,1) + 2]) / 4 = 1/4; Rf = (4 - [1 + 1 + 2]) / 4 = 0; HD = 1/8.
    a, b = np.array([0, 1, 2, 2]), np.array([0, 0, 1, 1])
    assert hamming_distance(a, b) == pytest.approx((0.125, 0.25, 0.0), abs=1e-15)
    # Swapping the arguments swaps the two rates and keeps the distance.
    assert hamming_distance(b, a) == pytest.approx((0.125, 0.0, 0.25), abs=1e-15)
    # Areas [1,3,2,2] (total 8): cells (0,0)=1, (1,0)=3, (2,1)=4.
    # Rm = (8 - [max(1,3) + 4]) / 8 = 1/8; Rf = (8 - [1 + 3 + 4]) / 8 = 0; HD = 1/16.
    r = hamming_distance(a, b, face_areas=np.array([1.0, 3.0, 2.0, 2.0]))
    assert r == pytest.approx((0.0625, 0.125, 0.0), abs=1e-15)


def test_hamming_one_segment_vs_parts():
    # pred = one segment, gt = two halves: every gt segment lies inside the one segment, so
    # Rm = 0; the one segment's best gt match covers half: Rf = 1/2; HD = 1/4.
    assert hamming_distance([0, 0, 0, 0], [0, 0, 1, 1]) == pytest.approx((0.25, 0.0, 0.5))


def test_hamming_identity_and_unit_weights():
    rng = np.random.default_rng(4)
    g = rng.integers(0, 6, 400)
    assert hamming_distance(g, g) == (0.0, 0.0, 0.0)
    a = rng.integers(0, 3, 400)
    assert hamming_distance(a, g) == pytest.approx(hamming_distance(a, g, np.ones(400)))


# ---------------------------------------------------------------------------------------------
# Consistency errors
# ---------------------------------------------------------------------------------------------

def test_consistency_hand_case_counts():
    # E(a,b,f) = |R_a(f) \ R_b(f)| / |R_a(f)|, E(b,a,f) the reverse.
    #   f0: R_a={0,1}, R_b={0,1,2}: E(a,b)=0,   E(b,a)=1/3
    #   f1: same as f0:             E(a,b)=0,   E(b,a)=1/3
    #   f2: R_a={2,3}, R_b={0,1,2}: E(a,b)=1/2, E(b,a)=2/3
    #   f3: R_a={2,3}, R_b={3}:     E(a,b)=1/2, E(b,a)=0
    # GCE = min(1, 4/3) / 4 = 0.25;  LCE = (0 + 0 + 1/2 + 0) / 4 = 0.125
    gce, lce = consistency_errors(A4, B4)
    assert gce == pytest.approx(0.25, abs=1e-15)
    assert lce == pytest.approx(0.125, abs=1e-15)


def test_consistency_area_variant_hand_case():
    # Areas [1,1,1,5]: |a0|=2, |a1|=6, |b0|=3, |b1|=5 (area); errors still averaged over 4 faces.
    #   f0, f1: cell area 2: E(a,b) = 1-2/2 = 0,   E(b,a) = 1-2/3 = 1/3
    #   f2:     cell area 1: E(a,b) = 1-1/6 = 5/6, E(b,a) = 1-1/3 = 2/3
    #   f3:     cell area 5: E(a,b) = 1-5/6 = 1/6, E(b,a) = 1-5/5 = 0
    # GCEa = min(1, 4/3) / 4 = 0.25;  LCEa = (0 + 0 + 2/3 + 0) / 4 = 1/6
    gce, lce = consistency_errors(A4, B4, face_areas=np.array([1.0, 1.0, 1.0, 5.0]))
    assert gce == pytest.approx(0.25, abs=1e-15)
    assert lce == pytest.approx(1 / 6, abs=1e-15)


def test_consistency_identities_and_symmetry():
    rng = np.random.default_rng(5)
    g = rng.integers(0, 5, 300)
    a = rng.integers(0, 4, 300)
    assert consistency_errors(g, g) == (0.0, 0.0)
    # A refinement has zero error both ways: one segment, every face, any sub-split of g.
    assert consistency_errors(np.zeros(300, int), g) == (0.0, 0.0)
    assert consistency_errors(np.arange(300), g) == (0.0, 0.0)
    assert consistency_errors(g * 2 + (rng.random(300) > 0.5), g) == (0.0, 0.0)
    gce, lce = consistency_errors(a, g)
    assert 0 <= lce <= gce <= 1
    assert consistency_errors(g, a) == pytest.approx((gce, lce), abs=1e-15)
    w = rng.random(300)
    assert consistency_errors(g, a, w) == pytest.approx(consistency_errors(a, g, w), abs=1e-15)


def test_consistency_matches_per_face_definition():
    rng = np.random.default_rng(6)
    for _ in range(20):
        n = int(rng.integers(2, 25))
        a, b = rng.integers(0, 4, n), rng.integers(0, 3, n)
        e_ab = np.array([np.sum((a == a[f]) & (b != b[f])) / np.sum(a == a[f]) for f in range(n)])
        e_ba = np.array([np.sum((b == b[f]) & (a != a[f])) / np.sum(b == b[f]) for f in range(n)])
        gce, lce = consistency_errors(a, b)
        assert gce == pytest.approx(min(e_ab.sum(), e_ba.sum()) / n, abs=1e-12)
        assert lce == pytest.approx(np.minimum(e_ab, e_ba).sum() / n, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# Cut discrepancy
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [3, 7, "every"])
def test_compare_segmentations_gives_each_metric_s_own_numbers(k):
    """One contingency table for the pair: the very numbers rand_index_error, hamming_distance
    (area weighted) and consistency_errors compute each on its own table of the same pair, for
    labels with gaps and negatives, and for "every face its own segment" (the sorted table)."""
    rng = np.random.default_rng(11)
    n = 5000
    b = rng.choice([-3, 0, 2, 9, 40], n)
    a = np.arange(n) * 7 - 5 if k == "every" else rng.integers(0, k, n) * 3
    areas = rng.random(n) + 0.1
    got = compare_segmentations(a, b, areas)
    hd = hamming_distance(a, b, areas)
    gce, lce = consistency_errors(a, b)
    want = {"rand_index_error": rand_index_error(a, b), "hamming_distance": hd.distance,
            "hamming_missing_rate": hd.missing_rate, "hamming_false_alarm_rate": hd.false_alarm_rate,
            "gce": gce, "lce": lce}
    assert got == want
    assert 0 < got["rand_index_error"] < 1 and 0 < got["hamming_distance"] < 1
    only_rand = compare_segmentations(a, b, hamming=False, consistency=False)
    assert only_rand == {"rand_index_error": want["rand_index_error"]}
    assert set(compare_segmentations(a, b, areas, rand=False)) == set(want) - {"rand_index_error"}


def test_average_radius_hand_case():
    v, f = strip_mesh()
    assert mesh_face_areas(v, f) == pytest.approx(np.full(6, 0.5))
    assert average_radius(v, f) == pytest.approx(STRIP_RADIUS, rel=1e-12)


def test_cut_discrepancy_hand_case():
    v, f = strip_mesh()
    a = np.array([0, 0, 1, 1, 1, 1])  # cut at x = 1: cut vertices (1,0), (1,1)
    b = np.array([0, 0, 0, 0, 1, 1])  # cut at x = 2: cut vertices (2,0), (2,1)
    # Each cut vertex is one unit edge from the other cut (the diagonals are sqrt2 long), so all
    # four distances are 1; mean 1, divided by the average radius 0.754683 -> 1.325058.
    cd = cut_discrepancy(v, f, a, b)
    assert cd == pytest.approx(1 / STRIP_RADIUS, rel=1e-12)
    assert cut_discrepancy(v, f, b, a) == pytest.approx(cd, rel=1e-15)


def test_cut_discrepancy_pools_both_directions():
    v, f = strip_mesh()
    a = np.array([0, 0, 1, 1, 1, 1])  # cut at x = 1 (2 cut vertices)
    b = np.array([0, 0, 1, 1, 2, 2])  # cuts at x = 1 and x = 2 (4 cut vertices)
    # a -> b: 0, 0. b -> a: 0, 0 (x=1), 1, 1 (x=2). The benchmark pools the six distances:
    # (0+0+0+0+1+1) / 6 = 1/3 (the paper's mean of directional means would give (0 + 1/2)/2).
    assert cut_discrepancy(v, f, a, b) == pytest.approx((1 / 3) / STRIP_RADIUS, rel=1e-12)


def test_cut_discrepancy_identity_symmetry_and_undefined():
    v, f = sphere_mesh()
    g = octant_labels(v, f)
    assert cut_discrepancy(v, f, g, g) == 0.0
    rng = np.random.default_rng(7)
    rot = v @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
    h = octant_labels(rot, f)
    cd = cut_discrepancy(v, f, g, h)
    assert cd > 0
    assert cut_discrepancy(v, f, h, g) == pytest.approx(cd, rel=1e-12)
    # No cut in one of them: the benchmark writes no value -> NaN.
    assert math.isnan(cut_discrepancy(v, f, np.zeros(len(f), int), g))
    assert math.isnan(cut_discrepancy(v, f, np.zeros(len(f), int), np.ones(len(f), int)))


def test_cut_discrepancy_scale_invariant():
    v, f = sphere_mesh(2)
    g = octant_labels(v, f)
    h = (v[f].mean(axis=1)[:, 2] > 0).astype(int)
    assert cut_discrepancy(3.5 * v, f, g, h) == pytest.approx(cut_discrepancy(v, f, g, h),
                                                              rel=1e-12)


def _cut_vertices_plainly(faces, labels):
    """Endpoints of every edge whose faces carry more than one label, edge by edge."""
    seen = {}
    for fi, tri in enumerate(faces.tolist()):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            if a != b:
                seen.setdefault((min(a, b), max(a, b)), set()).add(int(labels[fi]))
    return sorted({v for e, labs in seen.items() if len(labs) > 1 for v in e})


@pytest.mark.parametrize("mesh", ["sphere", "strip", "non-manifold"])
def test_cut_vertices_are_the_ends_of_edges_between_labels(mesh):
    """A closed mesh (every edge has two faces: one comparison per edge), a strip with boundary
    edges (never cut) and a fin of three faces on one edge: the vertices of the plain edge scan."""
    from torchakvf.evaluate.metrics import EdgeGraph

    if mesh == "sphere":
        v, f = sphere_mesh(2)
        labels = octant_labels(v, f)
    else:
        v, f = strip_mesh()
        labels = np.array([0, 0, 1, 1, 0, 2])
        if mesh == "non-manifold":                          # a third face on the edge 1-5
            v = np.concatenate([v, [[1.5, 0.5, 1.0]]])
            f = np.concatenate([f, [[1, 5, 8]]])
            labels = np.array([0, 0, 0, 0, 0, 0, 3])
    graph = EdgeGraph(v, f)
    assert (graph._face_pairs is not None) == (mesh == "sphere")
    got = graph.cut_vertices(labels)
    want = _cut_vertices_plainly(f, labels)
    assert len(want) > 0
    np.testing.assert_array_equal(got, want)
    assert got.dtype == np.int64


def test_one_graph_scoring_many_pairs_runs_dijkstra_once_per_labelling(monkeypatch):
    """A mesh's scorer keeps each labelling's distance to its cut: every pair gives the value of
    a fresh computation (bitwise), and Dijkstra runs once per distinct labelling, however the
    pairs repeat (a human against several predictions, the same labels in a new array)."""
    from torchakvf.evaluate.metrics import EdgeGraph
    v, f = sphere_mesh(2)
    c = v[f].mean(axis=1)
    labellings = [octant_labels(v, f), (c[:, 2] > 0).astype(np.int64), (c[:, 0] > 0.3).astype(np.int64),
                  np.zeros(len(f), dtype=np.int64)]
    graph = EdgeGraph(v, f)
    runs, real = [], graph.distance_to
    monkeypatch.setattr(graph, "distance_to", lambda src: runs.append(len(src)) or real(src))
    for a in labellings:
        for b in labellings:
            got = graph.cut_discrepancy(a.copy(), b.copy())
            want = cut_discrepancy(v, f, a, b)
            assert (math.isnan(got) and math.isnan(want)) or got == want
    assert len(runs) == 3                      # three labellings with a cut, one without


# ---------------------------------------------------------------------------------------------
# evaluate_segmentation and validation
# ---------------------------------------------------------------------------------------------

def test_evaluate_segmentation_combines_all():
    v, f = sphere_mesh()
    g = octant_labels(v, f)
    p = (v[f].mean(axis=1)[:, 2] > 0.1).astype(int) + 2 * (v[f].mean(axis=1)[:, 0] > 0)
    r = evaluate_segmentation(v, f, p, g)
    areas = mesh_face_areas(v, f)
    assert r["rand_index_error"] == rand_index_error(p, g)
    assert (r["hamming_distance"], r["hamming_missing_rate"], r["hamming_false_alarm_rate"]) \
        == tuple(hamming_distance(p, g, areas))
    assert (r["gce"], r["lce"]) == consistency_errors(p, g)
    assert (r["gce_area"], r["lce_area"]) == consistency_errors(p, g, areas)
    assert r["cut_discrepancy"] == cut_discrepancy(v, f, p, g)
    assert all(isinstance(x, float) for x in r.values())
    same = evaluate_segmentation(v, f, g, g)
    assert all(x == 0.0 for x in same.values())


@pytest.mark.parametrize("a, b, match", [
    ([0, 1, 1], [0, 1], "same faces"),
    ([0.0, 1.0], [0, 1], "integer"),
    ([[0, 1]], [[0, 1]], "1-D"),
    ([], [], "empty"),
    ([True, False], [0, 1], "integer"),
])
def test_label_validation(a, b, match):
    for fn in (rand_index_error, hamming_distance, consistency_errors):
        with pytest.raises(ValueError, match=match):
            fn(a, b)


def test_weight_and_mesh_validation():
    with pytest.raises(ValueError, match="one value per face"):
        hamming_distance(A4, B4, face_areas=[1.0, 2.0])
    with pytest.raises(ValueError, match="negative"):
        consistency_errors(A4, B4, face_areas=[1.0, -1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="NaN"):
        hamming_distance(A4, B4, face_areas=[1.0, np.nan, 1.0, 1.0])
    v, f = strip_mesh()
    with pytest.raises(ValueError, match="mesh has 6 faces"):
        cut_discrepancy(v, f, A4, B4)
    with pytest.raises(ValueError, match="outside"):
        cut_discrepancy(v, f + 10, np.zeros(6, int), np.zeros(6, int))
    with pytest.raises(ValueError, match=r"\[V, 3\]"):
        evaluate_segmentation(v[:, :2], f, np.zeros(6, int), np.zeros(6, int))


def test_matched_agreement_hand_cases():
    from torchakvf.evaluate.metrics import matched_agreement

    truth = np.array([0, 0, 0, 1, 1, 2])
    # Renamed labels are the same partition.
    assert matched_agreement(np.array([5, 5, 5, 3, 3, 9]), truth) == 1.0
    # One face of segment 0 put with segment 1: 5 of 6 faces match.
    assert matched_agreement(np.array([0, 0, 1, 1, 1, 2]), truth) == pytest.approx(5 / 6)
    # Two predicted segments against three true ones: the third true segment is unmatched.
    assert matched_agreement(np.array([0, 0, 0, 1, 1, 1]), truth) == pytest.approx(5 / 6)
    # Area weights: the face moved to segment 1 carries half the area, so the best matching
    # pairs predicted segment 1 with true segment 0 (area 5) and leaves faces 0, 1, 3, 4 out.
    area = np.array([1, 1, 5, 1, 1, 1], dtype=float)
    assert matched_agreement(np.array([0, 0, 1, 1, 1, 2]), truth, area) == pytest.approx(6 / 10)
