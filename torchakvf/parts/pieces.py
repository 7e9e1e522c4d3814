"""At most k parts: a mesh in more disconnected pieces than the k parts asked for would
otherwise keep one label per piece. :func:`limit_parts` merges the smallest parts, each into
the part it touches or else the nearest one, until k remain."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ParameterError
from ..mesh.clean import face_areas


def limit_parts(labels: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int) -> np.ndarray:
    """Labels [F] with at most ``k`` parts (labels >= 0; -1, the connecting region, is kept).

    labels : [F] int, a part per face of the mesh (vertices [V, 3], faces [F, 3]).
    Unchanged (the same array) when it has k parts or fewer. Otherwise, repeatedly, the part
    of least area (the smaller label on a tie) is merged into the part sharing the most
    vertices with it (the smaller label on a tie), or, where it touches none (a disconnected
    piece), into the part of the face centroid nearest to one of its own. The parts left are
    renumbered 0..k-1 in the order of their labels.
    """
    labels = np.asarray(labels)
    if int(k) < 1:
        raise ParameterError(f"k must be at least 1 part, got {k}")
    parts = np.unique(labels[labels >= 0])
    if len(parts) <= k:
        return labels
    faces = np.asarray(faces)
    out = labels.astype(np.int64, copy=True)
    area = np.bincount(np.searchsorted(parts, out[out >= 0]),
                       weights=face_areas(np.asarray(vertices, dtype=np.float64), faces)[out >= 0],
                       minlength=len(parts))
    centroids = np.asarray(vertices, dtype=np.float64)[faces].mean(axis=1)
    alive = np.ones(len(parts), dtype=bool)
    for _ in range(len(parts) - int(k)):
        live = np.flatnonzero(alive)
        small = live[np.lexsort((live, area[live]))[0]]
        into = _merge_target(out, faces, centroids, parts, small)
        out[out == parts[small]] = parts[into]
        area[into] += area[small]
        alive[small] = False
    kept = parts[alive]
    renumber = np.full(int(parts.max()) + 1, -1, dtype=np.int64)
    renumber[kept] = np.arange(len(kept))
    return np.where(out >= 0, renumber[np.maximum(out, 0)], out).astype(labels.dtype, copy=False)


def _merge_target(labels: np.ndarray, faces: np.ndarray, centroids: np.ndarray, parts: np.ndarray,
                  small: int) -> int:
    """Index (into ``parts``) of the part that part ``small`` merges into."""
    mine = labels == parts[small]
    others = (labels >= 0) & ~mine
    shared = np.zeros(faces.max() + 1, dtype=bool)
    shared[faces[mine].ravel()] = True
    touching = others & shared[faces].any(axis=1)
    if touching.any():
        # the neighbour sharing the most vertices with it
        cand = np.unique(labels[touching])
        votes = np.zeros(len(cand))
        for j, c in enumerate(cand):
            votes[j] = len(np.intersect1d(faces[labels == c].ravel(), faces[mine].ravel()))
        best = cand[np.lexsort((cand, -votes))[0]]
        return int(np.searchsorted(parts, best))
    other_faces = np.flatnonzero(others)
    distance, nearest = cKDTree(centroids[other_faces]).query(centroids[mine])
    best = labels[other_faces[nearest[np.argmin(distance)]]]
    return int(np.searchsorted(parts, best))


__all__ = ["limit_parts"]
