"""The graph-cut boundary stage (issue 12): alpha-expansion against a brute-force optimum."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

pytest.importorskip("gco", reason="gco-wrapper (a dependency: pip install -e .) not installed")

from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.mesh.clean import face_areas
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.graphcut import (GraphCut, allowed_labels, energy, graphcut_labels,
                                      potts_expansion)


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
    from torchakvf.errors import ParameterError
    import torchakvf as ta
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
