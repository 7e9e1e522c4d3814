"""Dual edges and crease weights (:mod:`torchakvf.parts.concavity`): the dihedral's sign and
angle, lengths in the unit-area frame, a convex surface, the saturation at the crease angle."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.planar_meshes import hinge

from torchakvf import shapes
from torchakvf.parts.concavity import crease_weights, dual_edges
from torchakvf.parts.merge import region_graph
from torchakvf.parts.topology import face_adjacency


@pytest.mark.parametrize("fold,expected", [(np.pi / 2, np.pi / 2), (-np.pi / 3, -np.pi / 3), (0.0, 0.0)])
def test_hinge_dihedral_sign_and_angle(fold, expected):
    v, f = hinge(fold)
    # The first face points up (+z), the fold sign convention relies on it.
    n0 = np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]])
    assert n0[2] > 0
    d = dual_edges(v, f)
    assert d.pairs.tolist() == [[0, 1]]
    np.testing.assert_allclose(d.length, [1.0], rtol=1e-12)
    np.testing.assert_allclose(d.dihedral, [expected], atol=1e-12)
    np.testing.assert_allclose(d.concavity, [max(expected, 0.0) / np.pi], atol=1e-12)


def test_lengths_are_in_the_unit_area_frame():
    # the hinge's two faces have area 1/2 each and share an edge of length 1: in any unit of
    # length the edge is 1 against a unit total area (what reads it is then free of the unit)
    v, f = hinge(np.pi / 4)
    for s in (2.0 ** -12, 1e-3, 7.5e4):
        np.testing.assert_allclose(dual_edges(v * s, f).length, [1.0], rtol=1e-12)
    # a unit square in two triangles: its diagonal sqrt(2) against area 1, whatever the size
    sq = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    for s in (1.0, 3.0, 2.0 ** -20):
        np.testing.assert_allclose(dual_edges(sq * s, tri).length, [np.sqrt(2)], rtol=1e-12)


def test_closed_convex_surface_is_convex_everywhere_and_pairs_match_adjacency():
    s = shapes.icosphere(2)
    d = dual_edges(s.vertices, s.faces)
    np.testing.assert_array_equal(d.pairs, face_adjacency(s.faces))
    assert (d.dihedral < 0).all() and d.concavity.max() == 0.0
    # Concavity flips with the orientation (inside-out sphere: every crease is a valley).
    assert (dual_edges(s.vertices, s.faces[:, ::-1]).dihedral > 0).all()


def test_crease_weights_saturate_at_the_crease_angle():
    cav, cvx = crease_weights(np.array([np.pi / 2, -np.pi / 8, 0.0, np.pi / 8]), np.pi / 4)
    np.testing.assert_allclose(cav, [1.0, 0.0, 0.0, 0.5])
    np.testing.assert_allclose(cvx, [0.0, 0.5, 0.0, 0.0])
    v, f = hinge(-np.pi / 3)
    g = region_graph(np.array([0, 1]), dual_edges(v, f), np.ones((2, 2)), np.ones(2))
    np.testing.assert_allclose(g.convex, [[0, 1 / 3], [1 / 3, 0]])
    np.testing.assert_allclose(g.concave, 0.0)
