"""The benchmark's cut discrepancy: how far the cut boundaries of two segmentations lie from
each other, in geodesic distance along mesh edges over the mesh's average radius (the conventions
matched are listed in :mod:`torchakvf.evaluate.metrics`)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..errors import ParameterError
from ..mesh.clean import face_areas as triangle_areas
from .metric_inputs import as_mesh, check_face_count, label_pair


def mesh_face_areas(vertices, faces) -> np.ndarray:
    """[F] float64 area of every triangle of ``vertices`` [V, 3] float, ``faces`` [F, 3] int."""
    v, f = as_mesh(vertices, faces)
    return triangle_areas(v, f)


def average_radius(vertices, faces) -> float:
    """Mean distance from a point on the surface to its centroid (GAPS ``AverageRadius``).

    Area-weighted mean, over faces, of the distance from the face centroid (mean of its three
    corners) to the area-weighted centroid of the surface. This is the cut discrepancy's
    normaliser.

    Parameters
    ----------
    vertices : array [V, 3], float
    faces : array [F, 3], int

    Returns
    -------
    float
        0 when the surface has zero area.
    """
    v, f = as_mesh(vertices, faces)
    return _average_radius(v, f, triangle_areas(v, f))


def _average_radius(v: np.ndarray, f: np.ndarray, areas: np.ndarray) -> float:
    total = float(areas.sum())
    if total <= 0:
        return 0.0
    centroids = v[f].mean(axis=1)
    center = (areas[:, None] * centroids).sum(axis=0) / total
    return float((areas * np.linalg.norm(centroids - center, axis=1)).sum() / total)


class EdgeGraph:
    """Edges of a triangle mesh, grouped with their incident faces, and the edge-length graph.

    Built once per mesh so several segmentations of the same mesh can be compared cheaply.
    """

    def __init__(self, vertices, faces):
        v, f = as_mesh(vertices, faces)
        self.vertices, self.faces = v, f
        n_v, n_f = len(v), len(f)
        ends = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        owner = np.tile(np.arange(n_f, dtype=np.int64), 3)
        lo, hi = ends.min(axis=1), ends.max(axis=1)
        keep = lo != hi  # a degenerate face's collapsed side is no edge
        lo, hi, owner = lo[keep], hi[keep], owner[keep]
        code = lo * n_v + hi
        order = np.argsort(code, kind="stable")
        code = code[order]
        #: faces incident to each edge, edge after edge; group k spans edge_start[k]:edge_start[k+1]
        self.edge_faces = owner[order]
        self.edge_start = np.flatnonzero(np.r_[True, code[1:] != code[:-1]])
        uniq = code[self.edge_start]
        #: [E, 2] the two faces of each edge where every edge has two (a closed manifold mesh,
        #: as every PSB mesh), else None: a cut test per edge is then one comparison
        two = self.edge_faces.size == 2 * self.edge_start.size and np.all(np.diff(self.edge_start) == 2)
        self._face_pairs = self.edge_faces.reshape(-1, 2) if two else None
        self.edge_ends = np.stack([uniq // n_v, uniq % n_v], axis=1)
        lengths = np.linalg.norm(v[self.edge_ends[:, 0]] - v[self.edge_ends[:, 1]], axis=1)
        # Zero-length edges stay in the graph as explicit zeros (csgraph keeps stored zeros
        # as edges), so "distance 0 from the cut" means what it means in the C++.
        self.graph = sp.csr_matrix((lengths, (self.edge_ends[:, 0], self.edge_ends[:, 1])),
                                   shape=(n_v, n_v))
        self._areas = None
        self._radius = None
        #: labels (their bytes) -> distance of every vertex to their cut (None: no cut). A scorer
        #: compares one human segmentation with several predictions (and one prediction with
        #: several humans), so each labelling's Dijkstra is run once per mesh.
        self._cut_distances: dict = {}

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def face_areas(self) -> np.ndarray:
        if self._areas is None:
            self._areas = triangle_areas(self.vertices, self.faces)
        return self._areas

    @property
    def average_radius(self) -> float:
        if self._radius is None:
            self._radius = _average_radius(self.vertices, self.faces, self.face_areas)
        return self._radius

    def cut_vertices(self, labels: np.ndarray) -> np.ndarray:
        """Vertices on a cut: endpoints of edges whose incident faces carry different labels.

        An edge with one incident face (mesh boundary) is never a cut, as in the benchmark; a
        non-manifold edge is a cut when any two of its faces differ.
        """
        if self.edge_start.size == 0:
            return np.empty(0, dtype=np.int64)
        if self._face_pairs is not None:
            is_cut = labels[self._face_pairs[:, 0]] != labels[self._face_pairs[:, 1]]
        else:
            lab = labels[self.edge_faces]
            is_cut = (np.minimum.reduceat(lab, self.edge_start)
                      != np.maximum.reduceat(lab, self.edge_start))
        on_cut = np.zeros(len(self.vertices), dtype=bool)      # the sorted unique cut vertices
        on_cut[self.edge_ends[is_cut].ravel()] = True
        return np.flatnonzero(on_cut)

    def distance_to(self, sources: np.ndarray) -> np.ndarray:
        """Edge-path distance from each vertex to the nearest source ([V]; inf: unreachable)."""
        return dijkstra(self.graph, directed=False, indices=sources, min_only=True)

    def cut_distance(self, labels: np.ndarray) -> np.ndarray | None:
        """[V] edge-path distance of each vertex to the cut of ``labels`` [F] (int64), None when
        it has no cut; kept per labelling (by value) for this mesh's later comparisons."""
        key = (labels.dtype.str, labels.shape, labels.tobytes())
        if key not in self._cut_distances:
            cut = self.cut_vertices(labels)
            self._cut_distances[key] = self.distance_to(cut) if cut.size else None
        return self._cut_distances[key]

    def cut_discrepancy(self, a: np.ndarray, b: np.ndarray) -> float:
        dist_a, dist_b = self.cut_distance(a), self.cut_distance(b)
        if dist_a is None or dist_b is None:
            return float("nan")  # the benchmark writes no CD entry here
        radius = self.average_radius
        if radius <= 0:
            raise ParameterError("the mesh has zero surface area, so the cut discrepancy "
                                 "(normalised by the average radius) is undefined")
        # Like the C++, "on a cut" means at distance 0 from it (its cut vertices, plus any vertex
        # joined to them by zero-length edges), and both directions are pooled into one mean.
        d = np.concatenate([dist_b[dist_a == 0], dist_a[dist_b == 0]])
        d = d[np.isfinite(d)]  # unreachable: other component (see module notes)
        if d.size == 0:
            return float("nan")
        return float(d.mean() / radius)


def cut_discrepancy(vertices, faces, a, b) -> float:
    """Cut discrepancy: how far the cut boundaries of two segmentations are from each other.

    For every vertex on a cut of ``a`` (an endpoint of an edge between faces of different
    segments) take its geodesic distance to the nearest cut vertex of ``b``, and vice versa;
    average all these distances (both directions pooled, as the benchmark's code does) and
    divide by the mesh's average radius (:func:`average_radius`). Geodesic distance is
    approximated, as in the benchmark, by the shortest path along mesh edges with Euclidean
    edge lengths (Dijkstra, ``scipy.sparse.csgraph``).

    Parameters
    ----------
    vertices : array [V, 3], float
    faces : array [F, 3], int
    a, b : array [F], int
        Face labels of the two segmentations. Symmetric in ``a`` and ``b``.

    Returns
    -------
    float
        >= 0; 0 when the cuts coincide. NaN when either segmentation has no cut (a single
        segment): the benchmark writes no value then and leaves the pair out of its averages,
        so aggregate with ``np.nanmean``.
    """
    graph = EdgeGraph(vertices, faces)
    a, b = label_pair(a, b)
    check_face_count(a, graph.n_faces, "a")
    return graph.cut_discrepancy(a, b)


__all__ = ["EdgeGraph", "average_radius", "cut_discrepancy", "mesh_face_areas"]
