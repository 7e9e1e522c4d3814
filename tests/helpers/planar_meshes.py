"""Planar test meshes: a disk for the operator and reference tests, a folded pair of triangles
(``hinge``) for the dihedral-angle and merge tests."""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay


def golden_disk(n_rings: int = 12):
    """Unit disk (V [N, 3] at z = 0, F [M, 3] counter-clockwise seen from +z): Delaunay
    triangulation of concentric rings (6r points on ring r), each rotated by a golden-angle
    multiple. Aligned rings would produce cocircular quads, i.e. exact right angles and star1 = 0
    on their diagonals (shapes.flat_disk has those, star1 ~ -1e-15); here every cotan weight is
    clearly positive."""
    pts = [np.zeros((1, 2))]
    for r in range(1, n_rings + 1):
        a = np.arange(6 * r) * (2 * np.pi / (6 * r)) + r * 2.399963
        pts.append(np.c_[np.cos(a), np.sin(a)] * (r / n_rings))
    pts = np.concatenate(pts)
    F = Delaunay(pts).simplices.copy()
    V = np.c_[pts, np.zeros(len(pts))]
    P = V[F]
    flip = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])[:, 2] < 0
    F[flip] = F[flip][:, ::-1]  # consistent orientation: interior left of the boundary
    return V, F


def hinge(fold: float):
    """Two unit right triangles sharing the edge (0,0,0)-(1,0,0); the first lies in z = 0 with
    normal +z, the second is rotated about the x axis by ``fold`` (> 0 folds it up: a valley)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, -1, 0], [0, np.cos(fold), np.sin(fold)]], dtype=float)
    f = np.array([[1, 0, 2], [0, 1, 3]])   # both counter-clockwise seen from +z when flat
    return v, f
