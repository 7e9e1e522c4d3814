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
from scipy.optimize import linear_sum_assignment

from .cut_discrepancy import EdgeGraph, average_radius, cut_discrepancy, mesh_face_areas
from .metric_inputs import as_weights, check_face_count, label_pair

__all__ = [
    "matched_agreement",
    "HammingResult",
    "rand_index_error",
    "hamming_distance",
    "consistency_errors",
    "compare_segmentations",
    "cut_discrepancy",
    "evaluate_segmentation",
    "mesh_face_areas",
    "average_radius",
    "EdgeGraph",
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
    a, b = label_pair(a, b)
    return _rand_index_error(_table(a, b))


def _rand_index_error(t: _Table) -> float:
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
    a, b = label_pair(a, b)
    w = as_weights(face_areas, a.size) if face_areas is not None else np.ones(a.size)
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
    a, b = label_pair(a, b)
    return _hamming_distance(_table(a, b, with_face_cell=True), face_areas)


def _hamming_distance(t: _Table, face_areas) -> HammingResult:
    w = np.ones(t.n_faces) if face_areas is None else as_weights(face_areas, t.n_faces)
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
    a, b = label_pair(a, b)
    return _consistency_errors(_table(a, b, with_face_cell=face_areas is not None), face_areas)


def _consistency_errors(t: _Table, face_areas) -> tuple[float, float]:
    freq = t.cell_count.astype(np.float64)  # faces in each cell: the per-face errors' multiplicity
    if face_areas is None:
        inter, size_a, size_b = freq, t.size_a.astype(np.float64), t.size_b.astype(np.float64)
    else:
        w = as_weights(face_areas, t.n_faces)
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
# all of them
# ---------------------------------------------------------------------------------------------

def compare_segmentations(a, b, face_areas=None, *, rand: bool = True, hamming: bool = True,
                          consistency: bool = True) -> dict:
    """The metrics of one pair that a contingency table gives, from one table: the numbers
    :func:`rand_index_error`, :func:`hamming_distance` (weighted by ``face_areas`` [F], as
    there) and :func:`consistency_errors` (faces counted) give one by one.

    Returns {"rand_index_error", "hamming_distance", "hamming_missing_rate",
    "hamming_false_alarm_rate", "gce", "lce"}: float each, those asked for.
    """
    a, b = label_pair(a, b)
    t = _table(a, b, with_face_cell=hamming)
    out = {}
    if rand:
        out["rand_index_error"] = _rand_index_error(t)
    if hamming:
        hd = _hamming_distance(t, face_areas)
        out.update(hamming_distance=hd.distance, hamming_missing_rate=hd.missing_rate,
                   hamming_false_alarm_rate=hd.false_alarm_rate)
    if consistency:
        out["gce"], out["lce"] = _consistency_errors(t, None)
    return out


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
    graph = EdgeGraph(vertices, faces)
    pred, gt = label_pair(pred, gt, ("pred", "gt"))
    check_face_count(pred, graph.n_faces, "pred")
    areas = graph.face_areas if face_areas is None else as_weights(face_areas, graph.n_faces)
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
