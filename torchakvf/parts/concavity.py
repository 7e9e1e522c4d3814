"""Signed dihedral angles on the dual graph (face pairs sharing an edge): concave vs convex.

The minima rule (Hoffman & Richards): people cut shapes along concave creases. A part
boundary running along a concave crease is a good cut; one crossing smooth or convex
surface is not. Host-side numpy, vectorized over the dual edges.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..mesh.batch import mesh_edges


class DualEdges(NamedTuple):
    """The dual graph of a triangle mesh with each dual edge's geometry.

    pairs : [P, 2] int64 faces sharing an edge (the order of
        :func:`torchakvf.parts.topology.face_adjacency`)
    length : [P] length of the shared edge in the unit-area frame (the mesh scaled to total area
        1), so that what reads it (the merge's boundary lengths against its area shares, the
        graph cut's cut costs) does not depend on the mesh's unit of length
    dihedral : [P] signed bending angle in radians, in [-π, π]: the angle between the two face
        normals, positive where the crease is concave (the surface folds towards its outward
        normals, a valley), negative where convex (a ridge), 0 on flat surface
    """

    pairs: np.ndarray
    length: np.ndarray
    dihedral: np.ndarray

    @property
    def concavity(self) -> np.ndarray:
        """[P] concave bending in [0, 1]: dihedral / π where concave, 0 where flat or convex."""
        return np.clip(self.dihedral, 0.0, None) / np.pi


def crease_weights(dihedral: np.ndarray, crease_angle: float = np.pi) -> tuple[np.ndarray, np.ndarray]:
    """([P] concave, [P] convex) bending weights in [0, 1] of signed dihedrals [P]: a bend θ
    counts min(|θ| / crease_angle, 1) on its side (concave θ > 0, convex θ < 0), 0 on the
    other; crease_angle = π gives :attr:`DualEdges.concavity` (linear in the angle)."""
    d = np.asarray(dihedral, dtype=np.float64)
    return (np.minimum(np.clip(d, 0.0, None) / crease_angle, 1.0),
            np.minimum(np.clip(-d, 0.0, None) / crease_angle, 1.0))


def dual_edges(vertices: np.ndarray, faces: np.ndarray) -> DualEdges:
    """Signed dihedral angles and lengths of the edges shared by two faces.

    vertices : [V, 3]; faces : [F, 3] consistently oriented (counter-clockwise from outside:
    the sign convention needs outward normals). Non-manifold edges pair up consecutive faces,
    as :func:`face_adjacency` does. A degenerate face (zero normal) bends by 0.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    _, face_edges, _ = mesh_edges(faces)
    flat = face_edges.reshape(-1)
    order = np.argsort(flat, kind="stable")
    e = flat[order]
    same = np.flatnonzero(e[1:] == e[:-1])
    slot_a, slot_b = order[same], order[same + 1]      # flat index 3 f + k: edge v_k -> v_k+1
    fa, fb = slot_a // 3, slot_b // 3
    ka, kb = slot_a % 3, slot_b % 3
    p0 = vertices[faces[fa, ka]]
    p1 = vertices[faces[fa, (ka + 1) % 3]]
    opp_b = vertices[faces[fb, (kb + 2) % 3]]
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, norm, out=np.zeros_like(normal), where=norm > 0)
    na, nb = normal[fa], normal[fb]
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", na, nb), -1.0, 1.0))
    # b's far vertex above a's plane (on its outward side): the surface folds up, a valley.
    height = np.einsum("ij,ij->i", na, opp_b - p0)
    degenerate = (norm[fa, 0] == 0) | (norm[fb, 0] == 0)
    dihedral = np.where(degenerate, 0.0, np.where(height > 0, angle, -angle))
    total = 0.5 * float(norm.sum())
    unit = 1.0 / np.sqrt(total) if total > 0 else 1.0
    return DualEdges(np.stack([fa, fb], axis=1), np.linalg.norm(p1 - p0, axis=1) * unit, dihedral)


__all__ = ["DualEdges", "crease_weights", "dual_edges"]
