"""Per-face crease cues of a mesh: how sharply, and how near, its surface turns inward.

People cut shapes along concave creases (the minima rule); the untangled fields do not see a
crease that no rigid motion changes across (a cup's handle, a bust's neck). These few columns
carry that geometry to the learned boundary probability
(:mod:`torchakvf.parts.boundary_probability`), measured as the segmentation's crease patches
measure it (:func:`~torchakvf.parts.creases.crease_band`: the normal change within a few dual
rings, concave bends only) and along the dual graph at unit area (as the part descriptors'
distances).

Columns (:data:`CUE_NAMES`), per face f of a mesh [F, 3]:

========================  ==========================================================================
``concave_edge``          largest concave dihedral of f's edges / π; [0, 1]
``concave_ring{r}``       1 − the least n_f·n_g over faces g within r dual rings that bend
                          concavely against f (:func:`~torchakvf.parts.creases.crease_band`'s
                          quantity); r = 1, 2, 3; [0, 2]
``crease_distance_{a}``   log(d + 0.005), d the unit-area dual-graph distance from f to the nearest
                          face whose ``concave_ring2`` exceeds 1 − cos(a) (a = 30°, 60°), capped at
                          0.2; about [−5.3, −1.6]
========================  ==========================================================================

All are functions of the surface alone (invariant to rigid motions, scale, numbering: rows
permute), but depend on the mesh's resolution: the descriptors compute them on the mesh their
fields are solved on (decimated to a few thousand faces).
"""
from __future__ import annotations

import math

import numpy as np

from .concavity import dual_edges
from .creases import least_cosine, unit_face_normals
from .part_descriptors import DISTANCE_FLOOR, distance_to_faces, dual_graph

#: Dual rings of the ring columns.
CUE_RINGS = (1, 2, 3)
#: Normal changes (degrees) whose nearest crease the distance columns measure.
CUE_ANGLES = (30, 60)
CUE_NAMES = (["concave_edge"] + [f"concave_ring{r}" for r in CUE_RINGS]
             + [f"crease_distance_{a}" for a in CUE_ANGLES])


def concave_ring_change(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray,
                        rings=CUE_RINGS) -> np.ndarray:
    """[F, len(rings)] float64: 1 − the least normal dot product of each face with the faces within
    r dual rings that bend concavely against it (``(c_g − c_f)·(n_g − n_f) < 0``), for r in
    ``rings`` (:func:`~torchakvf.parts.creases.least_cosine`); 0 where none does. pairs : [P, 2]
    faces sharing an edge."""
    unit = unit_face_normals(vertices, faces)
    centers = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)].mean(axis=1)
    return np.column_stack([1.0 - least_cosine(unit, pairs, r, centers, np.float64) for r in rings]) \
        if len(rings) else np.zeros((len(faces), 0))


def crease_cues(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[F, len(CUE_NAMES)] float64 crease cues (module docstring) of the mesh ``vertices`` [V, 3],
    ``faces`` [F, 3] (consistently oriented, outward normals)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = len(faces)
    dual = dual_edges(vertices, faces)
    edge = np.zeros(n_faces)
    concave = np.clip(dual.dihedral, 0.0, None) / np.pi
    np.maximum.at(edge, dual.pairs[:, 0], concave)
    np.maximum.at(edge, dual.pairs[:, 1], concave)
    rings = concave_ring_change(vertices, faces, dual.pairs)
    graph = dual_graph(vertices, faces)
    dist = []
    for a in CUE_ANGLES:
        crease = np.flatnonzero(rings[:, list(CUE_RINGS).index(2)] > 1.0 - math.cos(math.radians(a)))
        dist.append(np.log(distance_to_faces(graph, crease) + DISTANCE_FLOOR))
    return np.column_stack([edge, rings] + dist)


__all__ = ["CUE_ANGLES", "CUE_NAMES", "CUE_RINGS", "concave_ring_change", "crease_cues"]
