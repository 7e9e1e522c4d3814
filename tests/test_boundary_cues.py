"""torchakvf.parts.boundary_cues: per-face crease cues."""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from torchakvf import shapes
from torchakvf.parts.boundary_cues import CUE_NAMES, CUE_RINGS, concave_ring_change, crease_cues
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.part_descriptors import DISTANCE_CAP, DISTANCE_FLOOR, dual_graph


def _box(flip: bool = False):
    """A unit cube of 12 triangles, outward (convex edges) or, with ``flip``, inward: every edge
    between two sides then bends concavely by a right angle."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, (f[:, ::-1] if flip else f)


def test_a_convex_box_has_no_concave_cue_and_an_inverted_one_bends_by_right_angles():
    v, f = _box()
    assert (dual_edges(v, f).dihedral <= 1e-12).all()                 # outward: convex
    c = crease_cues(v, f)
    assert c.shape == (12, len(CUE_NAMES))
    np.testing.assert_array_equal(c[:, :4], 0.0)
    np.testing.assert_allclose(c[:, 4:], math.log(DISTANCE_CAP + DISTANCE_FLOOR))
    c = crease_cues(*_box(flip=True))
    # each triangle has one edge on its side's diagonal (flat) and two on the box's edges (90°)
    np.testing.assert_allclose(c[:, 0], 0.5)
    # within 1 and 2 rings the next sides (1 - cos 90°), within 3 the opposite side too (1 - cos 180°)
    np.testing.assert_allclose(c[:, 1:4], np.tile([1.0, 1.0, 2.0], (12, 1)), atol=1e-12)
    np.testing.assert_allclose(c[:, 4:], math.log(DISTANCE_FLOOR))  # every face is a crease face


def _ring_change_by_search(v, f, rings):
    """The ring columns face by face: faces within r dual hops (breadth-first), least dot product
    over those bending concavely."""
    dual = dual_edges(v, f)
    n = len(f)
    adj = sp.coo_matrix((np.ones(2 * len(dual.pairs)), (np.r_[dual.pairs[:, 0], dual.pairs[:, 1]],
                                                       np.r_[dual.pairs[:, 1], dual.pairs[:, 0]])), shape=(n, n))
    hops = dijkstra(adj.tocsr(), unweighted=True, limit=max(rings))
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    c = v[f].mean(axis=1)
    out = np.zeros((n, len(rings)))
    for i in range(n):
        for k, r in enumerate(rings):
            g = np.flatnonzero((hops[i] <= r) & (hops[i] >= 1))
            concave = ((c[g] - c[i]) * (nrm[g] - nrm[i])).sum(axis=1) < 0
            out[i, k] = 1.0 - min(1.0, (nrm[g[concave]] @ nrm[i]).min(initial=1.0))
    return out


def test_ring_columns_match_a_face_by_face_search_on_a_mug():
    s = shapes.mug()
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    got = concave_ring_change(v, f, dual_edges(v, f).pairs, CUE_RINGS)
    np.testing.assert_allclose(got, _ring_change_by_search(v, f, CUE_RINGS), atol=1e-12)
    assert (got[:, 1] > 0.5).any()                                  # the mug has concave creases


def test_distance_columns_are_the_distance_to_the_crease_faces_and_rows_follow_a_moved_renumbered_copy():
    s = shapes.mug()
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    c = crease_cues(v, f)
    crease = np.flatnonzero(c[:, 2] > 1.0 - math.cos(math.radians(30)))
    d = np.minimum(dijkstra(dual_graph(v, f), indices=crease, min_only=True), DISTANCE_CAP)
    np.testing.assert_allclose(c[:, 4], np.log(d + DISTANCE_FLOOR), atol=1e-12)
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    pv, pf = rng.permutation(len(v)), rng.permutation(len(f))
    moved = crease_cues((3.0 * v @ q.T + 1.5)[pv], np.argsort(pv)[f][pf])   # scaled too: unit-area lengths
    np.testing.assert_allclose(moved, c[pf], atol=1e-7)            # round-off of the moved normals
