"""The graph-cut boundary stage (:mod:`torchakvf.parts.graphcut`): alpha-expansion against a
brute-force optimum, the band, parts kept from emptying, and its inputs to gco (the band as
bit sets, corner means) against the straightforward constructions."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from helpers.partitions import sphere_labels

from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.mesh.clean import face_areas
from torchakvf.parts import graphcut as gc
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.graphcut import GraphCut, allowed_labels, energy, graphcut_labels, potts_expansion
from torchakvf.parts.topology import face_adjacency


def _brute(unary, pairs, w):
    n, k = unary.shape
    best, arg = np.inf, None
    for lab in itertools.product(range(k), repeat=n):
        e = energy(np.array(lab), unary, pairs, w)
        if e < best - 1e-12:
            best, arg = e, np.array(lab)
    return best, arg


def _tiny():
    """An octahedron: 8 faces, 12 dual edges (each face touches 3)."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return v, f


@pytest.mark.parametrize("seed", range(6))
def test_two_labels_expansion_is_the_exact_optimum(seed):
    v, f = _tiny()
    pairs = dual_edges(v, f).pairs
    rng = np.random.default_rng(seed)
    unary = rng.random((8, 2))
    w = 0.3 * rng.random(len(pairs))
    best, arg = _brute(unary, pairs, w)
    got = potts_expansion(unary, pairs, w)
    # energies go to gco as integers (6 digits of the largest term): equal up to that.
    assert energy(got, unary, pairs, w) == pytest.approx(best, abs=1e-3)


@pytest.mark.parametrize("seed", range(6))
def test_three_labels_expansion_within_the_potts_bound_and_usually_optimal(seed):
    v, f = _tiny()
    pairs = dual_edges(v, f).pairs
    rng = np.random.default_rng(100 + seed)
    unary = rng.random((8, 3))
    w = 0.4 * rng.random(len(pairs))
    best, _ = _brute(unary, pairs, w)
    e = energy(potts_expansion(unary, pairs, w), unary, pairs, w)
    assert best - 1e-9 <= e <= 2 * best + 1e-3    # alpha-expansion's guarantee for Potts
    assert e == pytest.approx(best, abs=1e-3)      # and on these tiny cases, the optimum


def test_zero_smoothness_takes_each_face_nearest_part_and_strong_smoothness_one_part():
    v, f = _tiny()
    d = dual_edges(v, f)
    area = face_areas(v, f)
    rng = np.random.default_rng(3)
    dist = rng.random((8, 3))
    labels = np.argmin(dist, axis=1)
    out = graphcut_labels(labels, dist, d, area, GraphCut(smoothness=0.0, band=8))
    np.testing.assert_array_equal(out, np.argmin(dist, axis=1))
    # strong smoothness: the solver alone puts every face in the part of least total data cost...
    one = potts_expansion(dist * (area / area.mean())[:, None], d.pairs, 1e3 * np.ones(len(d.pairs)))
    assert len(np.unique(one)) == 1 and one[0] == np.argmin(dist.sum(0))
    # ...but the stage gives emptied parts their faces back (it moves boundaries, keeps k)
    out = graphcut_labels(labels, dist, d, area, GraphCut(smoothness=1e3, beta=0.0, band=8))
    assert set(np.unique(out)) == set(np.unique(labels))


def test_band_keeps_far_parts_out_and_negative_faces_untouched():
    s = shapes.icosphere(2)
    d = dual_edges(s.vertices, s.faces)
    z = s.vertices[s.faces].mean(1)[:, 2]
    labels = np.where(z > 0, 0, 1)
    labels[:3] = -1
    dist = np.zeros((len(labels), 2))
    dist[:, 0] = 1.0   # label 1 looks best everywhere, but only a band may move to it
    out = graphcut_labels(labels, dist, d, face_areas(s.vertices, s.faces),
                          GraphCut(smoothness=1e-3, band=1))
    np.testing.assert_array_equal(out[:3], -1)
    reach = allowed_labels(labels[3:], np.zeros((0, 2), dtype=int), 2, 0)
    assert reach.sum() == len(labels) - 3
    moved = (out != labels) & (labels >= 0)
    assert moved.any() and (out[moved] == 1).all()
    assert (out[labels == 0] == 0).sum() > 0       # the far side of part 0 stays


def test_parameter_errors():
    with pytest.raises(ParameterError):
        GraphCut(smoothness=-1.0)
    with pytest.raises(ParameterError):
        GraphCut(crease_angle=0.0)
    with pytest.raises(ParameterError):
        GraphCut(band=-2)


def test_fixing_faces_beyond_the_band_gives_the_full_problem_optimum():
    # Two labels: both the reduced (band only) and the full constrained problem are solved
    # exactly by one expansion, so their energies must agree.
    s = shapes.icosphere(2)
    d = dual_edges(s.vertices, s.faces)
    area = face_areas(s.vertices, s.faces)
    z = s.vertices[s.faces].mean(1)[:, 2]
    labels = (z > 0.2).astype(int)
    rng = np.random.default_rng(7)
    dist = rng.random((len(labels), 2))
    opts = GraphCut(smoothness=0.5, band=2)
    out = graphcut_labels(labels, dist, d, area, opts)
    from torchakvf.parts.graphcut import edge_weights
    w = opts.smoothness * edge_weights(d, opts)
    unary = dist * (area / area.mean())[:, None]
    allowed = allowed_labels(labels, d.pairs, 2, opts.band)
    assert (~allowed).any() and (allowed.sum(1) == 2).any()
    full = potts_expansion(np.where(allowed, unary, 1e3), d.pairs, w)
    assert allowed[np.arange(len(out)), out].all()
    assert energy(out, unary, d.pairs, w) == pytest.approx(energy(full, unary, d.pairs, w), rel=1e-4)


def test_a_part_the_cut_would_empty_keeps_its_faces():
    s = shapes.icosphere(2)
    d = dual_edges(s.vertices, s.faces)
    z = s.vertices[s.faces].mean(1)[:, 2]
    labels = np.where(z > 0.8, 1, 0)          # a small cap
    dist = np.zeros((len(labels), 2))
    dist[:, 1] = 0.01                         # the cap barely prefers itself
    dist[labels == 1, 0] = 0.02
    out = graphcut_labels(labels, dist, d, face_areas(s.vertices, s.faces), GraphCut(smoothness=100.0, beta=0.0))
    assert set(np.unique(out)) == {0, 1}
    np.testing.assert_array_equal(out[labels == 1], 1)


def test_segment_graphcut_switch():
    """segment(graphcut=False) cuts no graph (recorded in params), True is the default, and a
    wrong value is a ParameterError."""
    import torchakvf as ta
    from torchakvf.errors import ParameterError
    from torchakvf.options import graphcut_option

    shape = shapes.mug(h=0.12)
    mesh = ta.Mesh(shape.vertices, shape.faces, "mug")
    on = ta.segment(mesh, 2, seed=0, refine=False)
    off = ta.segment(mesh, 2, seed=0, refine=False, graphcut=False)
    assert "graphcut" in on.meshes[0].params and "graphcut" not in off.meshes[0].params
    assert graphcut_option(True) == GraphCut() and graphcut_option(False) is None
    with pytest.raises(ParameterError, match="graphcut"):
        graphcut_option("yes")


@pytest.mark.parametrize("seed", range(4))
def test_components_solved_alone_on_their_own_labels(seed):
    """Two disjoint octahedra, four labels, each copy allowed two of them: solved component by
    component (each then an exact two-label cut), the labels are the brute-force optimum of
    each copy, and the energy that of the whole problem solved at once."""
    v, f = _tiny()
    pairs = dual_edges(v, f).pairs
    both = np.concatenate([pairs, pairs + 8])
    rng = np.random.default_rng(200 + seed)
    unary = rng.random((16, 4))
    w = 0.3 * rng.random(len(both))
    allowed = np.zeros((16, 4), dtype=bool)
    allowed[:8, [0, 2]] = True
    allowed[8:, [1, 3]] = True
    big = float(unary.max() + 2 * w.sum()) + 1.0
    costly = np.where(allowed, unary, big)
    got = potts_expansion(costly, both, w, allowed=allowed)
    assert allowed[np.arange(16), got].all()
    for half, labels in ((slice(0, 8), [0, 2]), (slice(8, 16), [1, 3])):
        e_half = w[:len(pairs)] if half.start == 0 else w[len(pairs):]
        best, arg = _brute(unary[half][:, labels], pairs, e_half)
        assert energy(np.searchsorted(labels, got[half]), unary[half][:, labels], pairs, e_half) == \
            pytest.approx(best, abs=1e-3)
    whole = potts_expansion(costly, both, w)
    assert energy(got, costly, both, w) == pytest.approx(energy(whole, costly, both, w), abs=1e-3)


def test_a_part_the_cut_would_shrink_below_the_fraction_keeps_its_faces():
    """A cap part (20% of the area) whose faces prefer the other part except at its tip: the
    cut alone leaves the tip (under 1%); with min_fraction 0.01 the part keeps its faces; a
    part that was under the fraction before the cut is cut as before."""
    s = shapes.icosphere(3)
    d = dual_edges(s.vertices, s.faces)
    area = face_areas(s.vertices, s.faces)
    z = s.vertices[s.faces].mean(1)[:, 2]
    labels = np.where(z > 0.6, 1, 0)
    dist = np.zeros((len(labels), 2))
    dist[:, 1] = 0.05                          # everywhere part 0 is nearer...
    dist[z > 0.985, 0], dist[z > 0.985, 1] = 0.05, 0.0   # ...but at the tip
    opts = GraphCut(smoothness=1e-3, beta=0.0, band=50)
    tip = (z > 0.985)
    assert 0 < area[tip].sum() / area.sum() < 0.01 < area[labels == 1].sum() / area.sum()
    cut = graphcut_labels(labels, dist, d, area, opts)
    np.testing.assert_array_equal(cut == 1, tip)
    kept = graphcut_labels(labels, dist, d, area, opts, min_fraction=0.01)
    np.testing.assert_array_equal(kept, labels)
    # under the fraction already (a cap of 2%, floor 5%): the cut takes it down to its tip
    small = np.where(z > 0.96, 1, 0)
    assert area[small == 1].sum() / area.sum() < 0.05
    np.testing.assert_array_equal(graphcut_labels(small, dist, d, area, opts, min_fraction=0.05) == 1, tip)


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
    v, f, labels = sphere_labels(3, k, seed=k + band)
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
    sites = np.flatnonzero(labels >= 0)                     # sorted: a site's row by bisection
    inside = (labels[dual.pairs] >= 0).all(axis=1)          # dual edges between two labelled faces
    pairs = np.searchsorted(sites, dual.pairs[inside]).reshape(-1, 2)
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
    v, f, labels = sphere_labels(3, k, seed)
    labels = labels.copy()
    rng = np.random.default_rng(seed)
    labels[rng.random(len(labels)) < 0.02] = -1                     # a few faces out of the cut
    dual = dual_edges(v, f)
    area = face_areas(v, f)
    dist = rng.random((len(labels), k))
    dist[rng.random(dist.shape) < 0.05] = np.inf
    opts = gc.GraphCut(smoothness=2.0, band=2)
    seen = []

    def record(unary, pairs, weights, cycles, allowed=None, engine=None, initial=None):
        seen.append((unary.copy(), pairs.copy(), weights.copy()))
        assert allowed is not None and allowed.shape == unary.shape and (allowed.sum(axis=1) > 1).all()
        assert engine == opts.engine and allowed[np.arange(len(unary)), initial].all()
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
    v, f, labels = sphere_labels(3, 4, seed=8)
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


def test_engine_option_and_its_errors():
    assert GraphCut().engine == "scipy"                 # the default needs no research-only code
    with pytest.raises(ParameterError, match="engine"):
        GraphCut(engine="maxflow")
    with pytest.raises(ParameterError, match="engine"):
        potts_expansion(np.zeros((2, 2)), np.array([[0, 1]]), np.ones(1), engine="maxflow")


@pytest.mark.parametrize("seed,k", [(0, 4), (1, 9), (2, 30)])
def test_engines_give_the_same_labels(seed, k):
    """The stage with scipy's maximum_flow and with gco: the same labels (from the parts, and
    from gco's first-label start) on random parts of a sphere and random data terms."""
    pytest.importorskip("gco", reason="gco-wrapper (the optional engine: pip install 'torchakvf[gco]') not installed")
    v, f, labels = sphere_labels(3, k, seed)
    rng = np.random.default_rng(seed)
    dual, area = dual_edges(v, f), face_areas(v, f)
    dist = rng.random((len(labels), k))
    for smooth in (0.3, 3.0):
        opts = GraphCut(smoothness=smooth, band=3)
        got = graphcut_labels(labels, dist, dual, area, opts)
        np.testing.assert_array_equal(got, graphcut_labels(labels, dist, dual, area,
                                                           GraphCut(smoothness=smooth, band=3, engine="gco")))
        assert (got != labels).any()
    allowed = allowed_labels(labels, dual.pairs, k, 3)
    unary = np.where(allowed, dist, 10.0)
    for cycles in (1, 2):
        np.testing.assert_array_equal(
            potts_expansion(unary, dual.pairs, 0.5 * np.ones(len(dual.pairs)), cycles, allowed),
            potts_expansion(unary, dual.pairs, 0.5 * np.ones(len(dual.pairs)), cycles, allowed, engine="gco"))


@pytest.mark.parametrize("seed", range(3))
def test_the_cut_starts_from_the_parts_so_never_raises_their_energy(seed):
    """Expansions from the parts only lower the stage's energy: the cut's labels cost at most
    what the parts cost (and less where a boundary moved)."""
    v, f, labels = sphere_labels(3, 6, seed)
    rng = np.random.default_rng(50 + seed)
    dual, area = dual_edges(v, f), face_areas(v, f)
    dist = rng.random((len(labels), 6))
    opts = GraphCut(smoothness=1.0, band=2)
    out = graphcut_labels(labels, dist, dual, area, opts)
    unary = dist * (area / area.mean())[:, None]
    w = opts.smoothness * gc.edge_weights(dual, opts)
    assert (out != labels).any()
    assert energy(out, unary, dual.pairs, w) < energy(labels, unary, dual.pairs, w)


def test_engine_gco_without_gco_wrapper_says_how_to_get_it(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "gco", None)                 # as if not installed
    with pytest.raises(ParameterError, match=r"torchakvf\[gco\]"):
        potts_expansion(np.zeros((2, 2)), np.array([[0, 1]]), np.ones(1), engine="gco")
    potts_expansion(np.zeros((2, 2)), np.array([[0, 1]]), np.ones(1))   # the default needs none


def test_engines_agree_on_sparse_problems_with_ties_and_lonely_faces():
    """Random sparse graphs (many components, single faces among them), few distinct costs
    (ties), random allowed labels and starts: component by component gco and scipy agree."""
    pytest.importorskip("gco", reason="gco-wrapper (the optional engine: pip install 'torchakvf[gco]') not installed")
    rng = np.random.default_rng(21)
    for _ in range(60):
        n, k = int(rng.integers(2, 30)), int(rng.integers(2, 6))
        pairs = rng.integers(0, n, size=(int(rng.integers(0, n)), 2))
        pairs = np.unique(np.sort(pairs[pairs[:, 0] != pairs[:, 1]], axis=1), axis=0)
        allowed = rng.random((n, k)) < 0.6
        allowed[np.arange(n), rng.integers(0, k, n)] = True
        unary = np.where(allowed, rng.integers(0, 4, (n, k)).astype(float), 50.0)
        w = rng.integers(0, 3, len(pairs)).astype(float)
        start = np.array([rng.choice(np.flatnonzero(row)) for row in allowed])
        for initial in (None, start):
            np.testing.assert_array_equal(
                potts_expansion(unary, pairs, w, 2, allowed=allowed, initial=initial),
                potts_expansion(unary, pairs, w, 2, allowed=allowed, initial=initial, engine="gco"))
