"""The four segmentation metrics of the Princeton Segmentation Benchmark (PSB).

Chen, Golovinskiy, Funkhouser, "A Benchmark for 3D Mesh Segmentation", SIGGRAPH 2009.
Every metric here follows the benchmark's own evaluator (``segEval`` / ``groupSegEval``,
C++ on top of the GAPS ``R3Mesh`` library), not just the paper's formulas, because the two
differ in small ways that change the numbers. All four are dissimilarities: 0 means the two
segmentations agree, larger is worse.

Argument order follows ``segEval fnMesh fnSeg fnSegRef``: the first segmentation (``a`` /
``pred``) is the one being evaluated, the second (``b`` / ``gt``) is the human reference.
Only the Hamming missing / false-alarm rates depend on that order; every other value here
is symmetric.

Conventions matched (and where we knowingly differ):

* **Segments are labels.** A segment is the set of faces sharing a label; it need not be
  connected (the benchmark does not split labels into connected components). Labels may be
  any integers (the benchmark needs ``0..k-1``; we compact them first, which is the same
  thing for its inputs).
* **Rand Index** - faces are *counted*, not area weighted, and pairs are *unordered pairs of
  distinct faces*: the denominator is ``C(N, 2) = N (N - 1) / 2``, not ``N^2``. The C++
  divides by ``(nFaces - 1) / 2`` in *integer* arithmetic, which for an even face count (every
  closed triangle mesh, so all of PSB) inflates 1 - RI by the factor ``(N - 1) / (N - 2)``
  (at most +0.04 % relative on PSB, whose smallest mesh has 2,682 faces). We use the exact
  ``C(N, 2)``; with it "one segment" and "every face its own segment" sum to exactly 1 against
  any reference, as the paper states.
* **Hamming distance** - the benchmark weights faces by *area* (``FaceArea``); pass
  ``face_areas`` to get its numbers (:func:`evaluate_segmentation` does). Without areas every
  face weighs 1.
* **Consistency error** - the benchmark's reported GCE / LCE count *faces*. It also writes an
  area variant (GCEa / LCEa) in which the per-face errors are ratios of *areas* but are still
  averaged over faces counted; ``consistency_errors(..., face_areas=...)`` reproduces that
  variant exactly.
* **Cut discrepancy** - distances are shortest paths along mesh edges (Dijkstra with
  Euclidean edge lengths, as the benchmark's ``ComputeDistancesFromVertices``), from the
  vertices on one segmentation's cut edges to the other's. The benchmark averages the
  distances of *both* directions pooled together (sum over both cut-vertex sets divided by
  the total number of cut vertices), which differs from the paper's mean of the two
  directional means when the two cuts have different lengths; we match the code. The
  normaliser is GAPS' ``R3Mesh::AverageRadius``: the area-weighted mean distance from face
  centroids to the area-weighted surface centroid. Where either segmentation has no cut at
  all the benchmark writes no CD value (its entry is NULL and is left out of averages); we
  return NaN. The one deliberate deviation: a cut vertex that cannot reach the other
  segmentation's cut (different connected component) would add ``FLT_MAX`` to the C++ sum;
  we leave such vertices out (every PSB mesh is one closed connected component, so the
  benchmark's numbers are unaffected).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import dijkstra

from ..errors import ParameterError
# (imported under a private name: several metrics take a face_areas= argument)
from ..mesh.clean import face_areas as _face_areas

__all__ = [
    "matched_agreement",
    "HammingResult",
    "rand_index_error",
    "hamming_distance",
    "consistency_errors",
    "cut_discrepancy",
    "evaluate_segmentation",
    "mesh_face_areas",
    "average_radius",
]


class HammingResult(NamedTuple):
    """Hamming distance of the benchmark, with its two directional parts.

    Attributes
    ----------
    distance : float
        ``(missing_rate + false_alarm_rate) / 2``, in [0, 1].
    missing_rate : float
        ``Rm = D_H(a => b) / |S|``: for every reference segment of ``b``, the part of it outside
        its best-overlapping segment of ``a``, summed and divided by the total weight.
    false_alarm_rate : float
        ``Rf = D_H(b => a) / |S|``: the same with the roles of ``a`` and ``b`` exchanged.
    """

    distance: float
    missing_rate: float
    false_alarm_rate: float


# ---------------------------------------------------------------------------------------------
# input checks
# ---------------------------------------------------------------------------------------------

def _as_labels(labels, name: str) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be a 1-D array of per-face segment labels, "
                             f"got shape {list(arr.shape)}")
    if arr.size == 0:
        raise ParameterError(f"{name} is empty: a segmentation needs at least one face")
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ParameterError(f"{name} must hold integer segment labels, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def _label_pair(a, b, names=("a", "b")) -> tuple[np.ndarray, np.ndarray]:
    a = _as_labels(a, names[0])
    b = _as_labels(b, names[1])
    if a.shape != b.shape:
        raise ParameterError(f"{names[0]} has {a.size} labels but {names[1]} has {b.size}: "
                             f"both segmentations must label the same faces")
    return a, b


def _as_weights(weights, n: int, name: str = "face_areas") -> np.ndarray:
    w = np.asarray(weights)
    if w.ndim != 1 or w.size != n:
        raise ParameterError(f"{name} must be a 1-D array with one value per face ({n}), "
                             f"got shape {list(w.shape)}")
    if not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise ParameterError(f"{name} must be numeric, got dtype {w.dtype}")
    w = w.astype(np.float64, copy=False)
    if not np.all(np.isfinite(w)):
        raise ParameterError(f"{name} contains NaN or infinite values")
    if np.any(w < 0):
        raise ParameterError(f"{name} contains negative values")
    if not w.sum() > 0:
        raise ParameterError(f"{name} sum to zero: the total weight must be positive")
    return w


def _as_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ParameterError(f"vertices must have shape [V, 3] with V > 0, got {list(v.shape)}")
    if not np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_:
        raise ParameterError(f"vertices must be numeric, got dtype {v.dtype}")
    v = v.astype(np.float64, copy=False)
    if not np.all(np.isfinite(v)):
        raise ParameterError("vertices contain NaN or infinite coordinates")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ParameterError(f"faces must be triangles with shape [F, 3] and F > 0, "
                             f"got {list(f.shape)}")
    if f.dtype == np.bool_ or not np.issubdtype(f.dtype, np.integer):
        raise ParameterError(f"faces must hold integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64, copy=False)
    if f.min() < 0 or f.max() >= len(v):
        raise ParameterError(f"faces index vertices outside 0..{len(v) - 1} "
                             f"(min {int(f.min())}, max {int(f.max())})")
    return v, f


# ---------------------------------------------------------------------------------------------
# contingency table
# ---------------------------------------------------------------------------------------------

def _compact(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map labels to ``0..k-1`` (increasing label order); return (per-face ids, segment sizes)."""
    lo, hi = int(labels.min()), int(labels.max())
    if lo >= 0 and hi < 2 * labels.size + 1024:
        # Benchmark-style labels (small non-negative ints): O(F + k) with no sort.
        counts = np.bincount(labels)
        present = counts > 0
        if present.all():
            return labels, counts
        remap = np.cumsum(present) - 1
        return remap[labels], counts[present]
    _, ids, sizes = np.unique(labels, return_inverse=True, return_counts=True)
    return ids.reshape(-1).astype(np.int64, copy=False), sizes


class _Table(NamedTuple):
    """Sparse contingency table: only the non-empty cells (a segment of a x a segment of b)."""

    n_faces: int
    ids_a: np.ndarray      # [F] compact segment of a per face
    ids_b: np.ndarray      # [F]
    size_a: np.ndarray     # [k1] faces per segment of a
    size_b: np.ndarray     # [k2]
    cell_a: np.ndarray     # [C] segment of a of each non-empty cell
    cell_b: np.ndarray     # [C]
    cell_count: np.ndarray  # [C] faces in each cell
    face_cell: np.ndarray | None  # [F] cell of each face (only when asked for)


def _table(a: np.ndarray, b: np.ndarray, with_face_cell: bool = False) -> _Table:
    ids_a, size_a = _compact(a)
    ids_b, size_b = _compact(b)
    k1, k2 = len(size_a), len(size_b)
    code = ids_a * k2 + ids_b
    face_cell = None
    # A dense k1*k2 table costs O(F + k1*k2); when that product is huge (e.g. "every face its
    # own segment" against itself) sort the F cell codes instead, O(F log F) with O(F) memory.
    if k1 * k2 <= 4 * code.size + (1 << 16):
        counts = np.bincount(code, minlength=k1 * k2)
        cells = np.flatnonzero(counts)
        cell_count = counts[cells]
        if with_face_cell:
            lookup = np.empty(k1 * k2, dtype=np.int64)
            lookup[cells] = np.arange(cells.size)
            face_cell = lookup[code]
    else:
        cells, inverse, cell_count = np.unique(code, return_inverse=True, return_counts=True)
        face_cell = inverse.reshape(-1) if with_face_cell else None
    cell_a, cell_b = np.divmod(cells, k2)
    return _Table(code.size, ids_a, ids_b, size_a, size_b, cell_a, cell_b, cell_count, face_cell)


def _pairs(n: np.ndarray) -> int:
    """Sum of C(n_i, 2), exact in int64 (PSB-sized meshes stay far below 2**63)."""
    n = n.astype(np.int64, copy=False)
    return int((n * (n - 1) // 2).sum())


# ---------------------------------------------------------------------------------------------
# Rand Index
# ---------------------------------------------------------------------------------------------

def rand_index_error(a, b) -> float:
    """1 - Rand Index between two face segmentations, as the benchmark reports it.

    The fraction of unordered pairs of distinct faces on which the segmentations disagree
    (one puts both faces in the same segment, the other does not)::

        1 - RI = [sum_i C(a_i, 2) + sum_j C(b_j, 2) - 2 sum_ij C(n_ij, 2)] / C(N, 2)

    with ``a_i``, ``b_j`` the segment sizes, ``n_ij`` the contingency table and ``N`` the number
    of faces. Faces are counted, not area weighted. Cost O(F + k1*k2) (O(F log F) when k1*k2 is
    much larger than F), never O(F^2).

    Parameters
    ----------
    a, b : array [F], int
        Segment label of every face. Symmetric in ``a`` and ``b``.

    Returns
    -------
    float
        In [0, 1]; 0 for identical segmentations (up to renaming of labels). A single face
        (no pairs) gives 0.

    Notes
    -----
    Pairs are counted as ``C(N, 2)`` (distinct faces, unordered), as the benchmark does; so for
    any reference ``g``, ``rand_index_error(one_segment, g) + rand_index_error(every_face, g)
    == 1`` exactly. The benchmark's C++ divides by an integer-truncated ``(N - 1) / 2``; see the
    module notes for the (< 0.04 %) difference this makes.
    """
    a, b = _label_pair(a, b)
    t = _table(a, b)
    n = t.n_faces
    if n < 2:
        return 0.0
    disagree = _pairs(t.size_a) + _pairs(t.size_b) - 2 * _pairs(t.cell_count)
    return float(disagree) / (n * (n - 1) / 2)


def matched_agreement(a, b, face_areas=None) -> float:
    """Fraction of faces (or of area, given ``face_areas``) on which ``a`` and ``b`` agree under
    the best one-to-one renaming of ``a``'s segments to ``b``'s (Hungarian matching of the
    contingency table; segments left unmatched count as disagreement). 1 = the same partition.
    Not a benchmark metric: what "labels match the true parts on x% of the area" means.
    """
    a, b = _label_pair(a, b)
    w = _as_weights(face_areas, a.size) if face_areas is not None else np.ones(a.size)
    t = _table(a, b, with_face_cell=True)
    weight = np.zeros((len(t.size_a), len(t.size_b)))
    weight[t.cell_a, t.cell_b] = np.bincount(t.face_cell, weights=w, minlength=len(t.cell_a))
    rows, cols = linear_sum_assignment(weight, maximize=True)
    return float(weight[rows, cols].sum() / w.sum())


# ---------------------------------------------------------------------------------------------
# Hamming distance
# ---------------------------------------------------------------------------------------------

def hamming_distance(a, b, face_areas=None) -> HammingResult:
    """Hamming distance (Huang & Dom 1995) between a segmentation and a reference.

    Each segment of one segmentation is matched to the segment of the other it overlaps most;
    the directional distance ``D_H(a => b) = sum over segments R_b of b of |R_b \\ best R_a|``.
    ``Rm = D_H(a => b) / |S|``, ``Rf = D_H(b => a) / |S|``, distance = ``(Rm + Rf) / 2``.

    Parameters
    ----------
    a : array [F], int
        The evaluated segmentation (``fnSeg`` of ``segEval``).
    b : array [F], int
        The reference segmentation (``fnSegRef``).
    face_areas : array [F], float, optional
        Weight of each face. The benchmark weights by face area, so pass the mesh's face areas
        (:func:`mesh_face_areas`) to reproduce its numbers. ``None`` counts faces (weight 1).

    Returns
    -------
    HammingResult
        ``(distance, missing_rate, false_alarm_rate)``, each in [0, 1]. Swapping ``a`` and
        ``b`` swaps the two rates and keeps ``distance``.
    """
    a, b = _label_pair(a, b)
    t = _table(a, b, with_face_cell=True)
    w = np.ones(t.n_faces) if face_areas is None else _as_weights(face_areas, t.n_faces)
    total = float(w.sum())
    inter = np.bincount(t.face_cell, weights=w, minlength=t.cell_count.size)
    # Best overlap of every segment of b (over segments of a), and vice versa. Empty cells
    # cannot be the maximum because all weights are >= 0, so the sparse cells suffice.
    best_for_b = np.zeros(len(t.size_b))
    np.maximum.at(best_for_b, t.cell_b, inter)
    best_for_a = np.zeros(len(t.size_a))
    np.maximum.at(best_for_a, t.cell_a, inter)
    missing = max(0.0, float(total - best_for_b.sum()) / total)
    false_alarm = max(0.0, float(total - best_for_a.sum()) / total)
    return HammingResult((missing + false_alarm) / 2, missing, false_alarm)


# ---------------------------------------------------------------------------------------------
# Consistency errors
# ---------------------------------------------------------------------------------------------

def consistency_errors(a, b, face_areas=None) -> tuple[float, float]:
    """Global and local consistency error (Martin et al., ICCV 2001), as the benchmark has them.

    With ``R(S, f)`` the segment of ``S`` containing face ``f``, the per-face refinement error
    ``E(S1, S2, f) = |R(S1, f) \\ R(S2, f)| / |R(S1, f)|`` and::

        GCE = min(sum_f E(a, b, f), sum_f E(b, a, f)) / N
        LCE = sum_f min(E(a, b, f), E(b, a, f)) / N

    Both are 0 when one segmentation refines the other (in particular for identical ones, for
    "one segment" and for "every face its own segment"), and LCE <= GCE.

    Parameters
    ----------
    a, b : array [F], int
        Face labels. Symmetric in ``a`` and ``b``.
    face_areas : array [F], float, optional
        ``None`` (default): ``|.|`` counts faces - the GCE / LCE the benchmark reports.
        Given: ``|.|`` is the area, reproducing the benchmark's secondary "GCEa / LCEa" columns;
        like the C++, the per-face errors are still averaged over faces *counted* (sum over
        faces divided by N), only the ratios inside ``E`` use areas. A segment of zero total
        area contributes error 0.

    Returns
    -------
    (gce, lce) : tuple of float, each in [0, 1]
    """
    a, b = _label_pair(a, b)
    t = _table(a, b, with_face_cell=face_areas is not None)
    freq = t.cell_count.astype(np.float64)  # faces in each cell: the per-face errors' multiplicity
    if face_areas is None:
        inter, size_a, size_b = freq, t.size_a.astype(np.float64), t.size_b.astype(np.float64)
    else:
        w = _as_weights(face_areas, t.n_faces)
        inter = np.bincount(t.face_cell, weights=w, minlength=freq.size)
        size_a = np.bincount(t.ids_a, weights=w, minlength=len(t.size_a))
        size_b = np.bincount(t.ids_b, weights=w, minlength=len(t.size_b))
    e_ab = _refinement_error(inter, size_a[t.cell_a])
    e_ba = _refinement_error(inter, size_b[t.cell_b])
    n = t.n_faces
    gce = min(float((freq * e_ab).sum()), float((freq * e_ba).sum())) / n
    lce = float((freq * np.minimum(e_ab, e_ba)).sum()) / n
    return max(0.0, gce), max(0.0, lce)


def _refinement_error(inter: np.ndarray, segment_size: np.ndarray) -> np.ndarray:
    """1 - |cell| / |segment| per cell, 0 where the segment has no measure (zero area)."""
    out = np.zeros_like(inter)
    ok = segment_size > 0
    out[ok] = 1.0 - inter[ok] / segment_size[ok]
    return np.clip(out, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# Cut discrepancy
# ---------------------------------------------------------------------------------------------

def mesh_face_areas(vertices, faces) -> np.ndarray:
    """Area of every triangle.

    Parameters
    ----------
    vertices : array [V, 3], float
    faces : array [F, 3], int

    Returns
    -------
    array [F], float64
    """
    v, f = _as_mesh(vertices, faces)
    return _face_areas(v, f)


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
    v, f = _as_mesh(vertices, faces)
    return _average_radius(v, f, _face_areas(v, f))


def _average_radius(v: np.ndarray, f: np.ndarray, areas: np.ndarray) -> float:
    total = float(areas.sum())
    if total <= 0:
        return 0.0
    centroids = v[f].mean(axis=1)
    center = (areas[:, None] * centroids).sum(axis=0) / total
    return float((areas * np.linalg.norm(centroids - center, axis=1)).sum() / total)


class _EdgeGraph:
    """Edges of a triangle mesh, grouped with their incident faces, and the edge-length graph.

    Built once per mesh so several segmentations of the same mesh can be compared cheaply.
    """

    def __init__(self, vertices, faces):
        v, f = _as_mesh(vertices, faces)
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
            self._areas = _face_areas(self.vertices, self.faces)
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
        lab = labels[self.edge_faces]
        is_cut = (np.minimum.reduceat(lab, self.edge_start)
                  != np.maximum.reduceat(lab, self.edge_start))
        return np.unique(self.edge_ends[is_cut].ravel())

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
    graph = _EdgeGraph(vertices, faces)
    a, b = _label_pair(a, b)
    _check_face_count(a, graph.n_faces, "a")
    return graph.cut_discrepancy(a, b)


def _check_face_count(labels: np.ndarray, n_faces: int, name: str) -> None:
    if labels.size != n_faces:
        raise ParameterError(f"{name} has {labels.size} labels but the mesh has {n_faces} faces")


# ---------------------------------------------------------------------------------------------
# all of them
# ---------------------------------------------------------------------------------------------

def evaluate_segmentation(vertices, faces, pred, gt, face_areas=None) -> dict:
    """All benchmark metrics of one segmentation against one reference segmentation.

    Parameters
    ----------
    vertices : array [V, 3], float
    faces : array [F, 3], int
    pred : array [F], int
        The evaluated segmentation (``fnSeg`` of ``segEval``).
    gt : array [F], int
        The human reference (``fnSegRef``).
    face_areas : array [F], float, optional
        Face weights for the area-weighted values; default: the mesh's triangle areas, which is
        what the benchmark uses.

    Returns
    -------
    dict[str, float]
        ``rand_index_error`` (1 - RI, faces counted), ``hamming_distance``,
        ``hamming_missing_rate``, ``hamming_false_alarm_rate`` (area weighted), ``gce``, ``lce``
        (faces counted: the benchmark's reported consistency errors), ``gce_area``,
        ``lce_area`` (the benchmark's GCEa / LCEa variant), ``cut_discrepancy`` (NaN when either
        segmentation has no cut). A mesh's benchmark score is the mean of these over its human
        segmentations (``np.nanmean`` for the cut discrepancy).
    """
    graph = _EdgeGraph(vertices, faces)
    pred, gt = _label_pair(pred, gt, ("pred", "gt"))
    _check_face_count(pred, graph.n_faces, "pred")
    areas = graph.face_areas if face_areas is None else _as_weights(face_areas, graph.n_faces)
    hd = hamming_distance(pred, gt, areas)
    gce, lce = consistency_errors(pred, gt)
    gce_area, lce_area = consistency_errors(pred, gt, areas)
    return {
        "rand_index_error": rand_index_error(pred, gt),
        "hamming_distance": hd.distance,
        "hamming_missing_rate": hd.missing_rate,
        "hamming_false_alarm_rate": hd.false_alarm_rate,
        "gce": gce,
        "lce": lce,
        "gce_area": gce_area,
        "lce_area": lce_area,
        "cut_discrepancy": graph.cut_discrepancy(pred, gt),
    }
