"""Midpoint subdivision of a cleaned mesh, its faces still mapped to the input's: for a mesh
with too few edges for the fields a segmentation needs (a 12-face cube asked for 5 parts)."""
from __future__ import annotations

import numpy as np

from .clean import CleanMesh, undirected_edges


def subdivide(clean: CleanMesh, levels: int = 1) -> CleanMesh:
    """``clean`` with every face split into 4 at its edge midpoints, ``levels`` times (4^levels
    faces per face; the surface and its orientation are unchanged).

    The children of a face follow one another, the middle one last, and all map to the
    parent's input face (``face_index``): per-face values scattered back to the input
    (:meth:`CleanMesh.to_input_faces`, :meth:`CleanMesh.labels_to_input_faces`) take the middle
    child's, one value per face of the file. ``report["subdivided"]`` records the levels.
    """
    vertices, faces = clean.vertices, clean.faces
    face_index, component = clean.face_index, clean.face_component
    for _ in range(int(levels)):
        table = undirected_edges(faces)
        mid = len(vertices) + table.inverse.reshape(-1, 3)       # [F, 3] midpoint of edge (v_k, v_k+1)
        vertices = np.concatenate([vertices, vertices[table.unique].mean(axis=1)])
        a, b, c = faces.T
        ab, bc, ca = mid.T
        faces = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                          np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)], axis=1).reshape(-1, 3)
        face_index, component = np.repeat(face_index, 4), np.repeat(component, 4)
    report = dict(clean.report, subdivided=int(levels))
    return CleanMesh(vertices=vertices, faces=faces, face_index=face_index,
                     n_input_faces=clean.n_input_faces, face_component=component, name=clean.name,
                     input_faces=clean.input_faces, report=report)


def levels_to_fit(clean: CleanMesh, n_edges_needed: int) -> int:
    """The fewest subdivision levels after which ``clean`` has at least ``n_edges_needed``
    edges (a level maps E edges and F faces to 2E + 3F edges and 4F faces)."""
    e, f = len(undirected_edges(clean.faces).unique), len(clean.faces)
    levels = 0
    while e < n_edges_needed:
        e, f, levels = 2 * e + 3 * f, 4 * f, levels + 1
    return levels


__all__ = ["subdivide", "levels_to_fit"]
