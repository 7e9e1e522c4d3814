"""Boundaries on the creases: a multi-label graph cut on the dual graph (faces = sites).

After the parts are chosen (k-means, merging), each face's part is re-decided by minimizing

    E(L) = Σ_f (a_f / ā) D[f, L_f]  +  λ Σ_{(f, g) dual edges} (ℓ_fg / ℓ̄) c_fg [L_f ≠ L_g]

* data term D [F, k]: the face's distance to each part (the mean over its corners of the
  per-vertex distance fields the isolines are cut from), weighted by face area a_f;
* smoothness: a cut across a dual edge costs its length ℓ_fg, less where the surface bends
  concavely (the minima rule): c_fg = 1 / (1 + β w_fg), w_fg = min(θ_fg / crease_angle, 1)
  on concave creases (θ > 0), 0 elsewhere (:func:`~torchakvf.parts.concavity.crease_weights`);
* a band: a face may only take a part present within ``band`` dual rings of it, so the cut
  moves boundaries and never relabels a far-away region with look-alike features (which
  would make a part disconnected).

The minimization is alpha-expansion (Boykov, Veksler & Zabih 2001) with the gco library
(Veksler & Delong) through gco-wrapper: the field's standard solver for Potts energies; with
two labels one expansion is an exact minimum cut.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import ParameterError
from .concavity import DualEdges, crease_weights


@dataclass(frozen=True)
class GraphCut:
    """Parameters of :func:`graphcut_labels`: smoothness λ (dimensionless: edge lengths over
    the mean length, areas over the mean area), concave-crease discount β, crease_angle
    (radians) at which a crease counts fully, band (dual rings a boundary may move)."""

    smoothness: float = 1.0
    beta: float = 10.0
    crease_angle: float = np.pi / 4
    band: int = 6

    def __post_init__(self):
        if not self.smoothness >= 0 or not self.beta >= 0:
            raise ParameterError(f"graph cut smoothness and beta must be >= 0, got {self.smoothness!r}, {self.beta!r}")
        if not 0 < self.crease_angle <= np.pi:
            raise ParameterError(f"graph cut crease_angle must be in (0, π], got {self.crease_angle!r}")
        if not (isinstance(self.band, (int, np.integer)) and self.band >= 0):
            raise ParameterError(f"graph cut band must be an integer >= 0, got {self.band!r}")


def _gco():
    try:
        import gco
    except ImportError as e:   # optional dependency: only the graph-cut stage needs it
        raise ParameterError("the graph-cut stage needs gco-wrapper: pip install 'torchakvf[graphcut]' "
                             "(or pip install gco-wrapper)") from e
    return gco


def edge_weights(dual: DualEdges, opts: GraphCut) -> np.ndarray:
    """[P] cost of cutting each dual edge: (ℓ / ℓ̄) / (1 + β w_concave) (see the module notes)."""
    cav, _ = crease_weights(dual.dihedral, opts.crease_angle)
    scale = max(float(dual.length.mean()), 1e-300) if len(dual.length) else 1.0
    return (dual.length / scale) / (1.0 + opts.beta * cav)


def allowed_labels(labels: np.ndarray, pairs: np.ndarray, k: int, band: int) -> np.ndarray:
    """[F, k] bool: part l occurs within ``band`` dual rings of face f (its own part always)."""
    n = len(labels)
    ok = labels >= 0
    reach = sp.csr_matrix((np.ones(int(ok.sum())), (np.flatnonzero(ok), labels[ok])), shape=(n, k))
    if band > 0 and len(pairs):
        adj = sp.coo_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]],
                                                       np.r_[pairs[:, 1], pairs[:, 0]])), shape=(n, n))
        step = (adj + sp.identity(n)).tocsr()
        for _ in range(band):
            reach = step @ reach
            reach.data[:] = 1.0
    return reach.toarray() > 0


def energy(labels: np.ndarray, unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> float:
    """E(L) = Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b] (p = (a, b) = pairs[p])."""
    labels = np.asarray(labels)
    return float(unary[np.arange(len(labels)), labels].sum()
                 + weights[labels[pairs[:, 0]] != labels[pairs[:, 1]]].sum())


def potts_expansion(unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """argmin-ish of Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b] by alpha-expansion (gco).

    unary : [F, k] float; pairs : [P, 2] site pairs; weights : [P] >= 0. Returns [F] int64.
    gco works in integers (energies scaled by their maximum, 5 digits kept for the data term).
    """
    gco = _gco()
    unary = np.ascontiguousarray(unary, dtype=np.float64)
    k = unary.shape[1]
    if k == 1 or len(unary) == 0:
        return np.zeros(len(unary), dtype=np.int64)
    e = np.sort(np.asarray(pairs, dtype=np.int64), axis=1)
    keep = e[:, 0] != e[:, 1]
    potts = np.ascontiguousarray(1.0 - np.eye(k))
    out = gco.cut_general_graph(np.ascontiguousarray(e[keep], dtype=np.int32),
                                np.ascontiguousarray(np.asarray(weights, dtype=np.float64)[keep]),
                                unary, potts, n_iter=-1, algorithm="expansion")
    return np.asarray(out, dtype=np.int64)


def graphcut_labels(labels: np.ndarray, distances: np.ndarray, dual: DualEdges, face_area: np.ndarray,
                    opts: GraphCut | None = None) -> np.ndarray:
    """Face labels [F] re-decided by the graph cut (see the module notes).

    labels : [F] parts 0..k-1 (faces < 0 are left as they are and out of the cut);
    distances : [F, k] each face's distance to each part (inf where a part is absent);
    dual : the mesh's :func:`~torchakvf.parts.concavity.dual_edges`; face_area : [F].
    """
    opts = GraphCut() if opts is None else opts
    labels = np.asarray(labels)
    k = distances.shape[1]
    if k <= 1:
        return labels.copy()
    sites = np.flatnonzero(labels >= 0)
    index = np.full(len(labels), -1, dtype=np.int64)
    index[sites] = np.arange(len(sites))
    pa, pb = index[dual.pairs[:, 0]], index[dual.pairs[:, 1]]
    inside = (pa >= 0) & (pb >= 0)
    pairs = np.stack([pa[inside], pb[inside]], axis=1)
    w = opts.smoothness * edge_weights(dual, opts)[inside]
    area = np.asarray(face_area, dtype=np.float64)[sites]
    d = np.asarray(distances, dtype=np.float64)[sites]
    finite = np.isfinite(d)
    d = np.where(finite, d, 0.0)
    unary = d * (area / max(float(area.mean()), 1e-300))[:, None]
    allowed = allowed_labels(labels[sites], pairs, k, opts.band) & finite
    # A forbidden label costs more than any face could gain by taking it (its own data term
    # plus every cut edge around it), so it is never chosen; kept finite for gco's integers.
    incident = np.bincount(pairs.ravel(), weights=np.r_[w, w], minlength=len(sites))
    big = float(unary.max(initial=0.0) + incident.max(initial=0.0)) + 1.0
    unary = np.where(allowed, unary, big)
    out = labels.copy()
    out[sites] = potts_expansion(unary, pairs, w)
    return out


__all__ = ["GraphCut", "graphcut_labels", "potts_expansion", "energy", "edge_weights", "allowed_labels"]
