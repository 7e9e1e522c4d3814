"""Face adjacency and connected pieces of labelled faces (host-side, numpy/scipy)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..mesh.batch import mesh_edges


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """[P, 2] pairs of faces sharing an edge."""
    _, face_edges, _ = mesh_edges(faces)
    flat = face_edges.reshape(-1)
    order = np.argsort(flat, kind="stable")
    e = flat[order]
    same = np.flatnonzero(e[1:] == e[:-1])
    return np.stack([order[same] // 3, order[same + 1] // 3], axis=1)


def labelled_pieces(labels: np.ndarray, adjacency: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected pieces of faces with equal labels: (count, piece id per face [F])."""
    a, b = adjacency[:, 0], adjacency[:, 1]
    keep = labels[a] == labels[b]
    n = len(labels)
    graph = sp.coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n, n))
    return connected_components(graph, directed=False)


def piece_neighbours(piece: np.ndarray, labels: np.ndarray, adjacency: np.ndarray
                     ) -> dict[int, dict[int, int]]:
    """For each piece, {neighbouring label: number of shared edges}."""
    out: dict[int, dict[int, int]] = {}
    a, b = adjacency[:, 0], adjacency[:, 1]
    cross = piece[a] != piece[b]
    for pa, lb in ((piece[a][cross], labels[b][cross]), (piece[b][cross], labels[a][cross])):
        for p, lab in zip(pa.tolist(), lb.tolist()):
            d = out.setdefault(p, {})
            d[lab] = d.get(lab, 0) + 1
    return out


def piece_label_counts(piece: np.ndarray, labels: np.ndarray, adjacency: np.ndarray,
                       weights: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`piece_neighbours` as arrays: (piece [M], neighbouring label [M], shared edges [M],
    first [M]) for each distinct (piece, label) pair, ordered by piece then label. ``first`` is
    the pair's rank in the order piece_neighbours inserts its dict keys (the edges' a-sides
    first, then their b-sides, each in edge order), so ties can be broken as a max over that
    dict would break them. weights : [P] a weight per adjacency pair; the shared edges are then
    their summed weights (float) instead of their count."""
    a, b = adjacency[:, 0], adjacency[:, 1]
    cross = piece[a] != piece[b]
    p = np.r_[piece[a][cross], piece[b][cross]].astype(np.int64)
    lab = np.r_[labels[b][cross], labels[a][cross]].astype(np.int64)
    if len(p) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty, empty
    span = int(lab.max()) - int(lab.min()) + 1
    key = p * span + (lab - lab.min())
    uniq, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    if weights is not None:
        counts = np.bincount(inverse, weights=np.r_[weights[cross], weights[cross]], minlength=len(uniq))
    return uniq // span, uniq % span + lab.min(), counts, first
