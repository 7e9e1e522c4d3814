"""Between two merges of one over-segmentation, the one whose weakest boundary lies on a crease.

People cut shapes where the surface turns inward (the minima rule), and a partition is as
wrong as its worst cut: a boundary across smooth surface splits one part in two. The learned
merge (:class:`~torchakvf.options.MergeWeights`) reads many cues and weighs the size of what it
joins, and on shapes it was not fitted on it can keep such a cut: a wheel's rim left in arcs,
its spokes joined to the hub instead. A second merge of the same pieces by concavity and
symmetry alone (the hand-set cost) cuts at the fillets there. Each partition is scored by its
weakest boundary, the least length-weighted mean concave bending over the pairs of adjacent
parts (:func:`weakest_boundary`), on the boundaries the graph cut leaves (it moves them onto
the nearest concave crease, and a cut with no crease near it stays on smooth surface); the
second replaces the first where its weakest boundary bends more than ``ratio`` times as much
and more than ``floor`` (:func:`prefers_other`).
"""
from __future__ import annotations

import numpy as np

from .concavity import DualEdges


def boundary_concavity(labels: np.ndarray, dual: DualEdges) -> np.ndarray:
    """[B] mean concave bending (:attr:`~torchakvf.parts.concavity.DualEdges.concavity`, the
    dihedral over π where concave, 0 elsewhere), weighted by edge length, along each boundary
    between two adjacent parts of ``labels`` [F] (negative labels: no part; their edges are
    no boundary), in the order of (smaller label, larger label)."""
    labels = np.asarray(labels, dtype=np.int64)
    la, lb = labels[dual.pairs[:, 0]], labels[dual.pairs[:, 1]]
    cut = (la != lb) & (la >= 0) & (lb >= 0)
    if not cut.any():
        return np.zeros(0)
    n = int(labels.max()) + 1
    key = np.minimum(la, lb)[cut] * n + np.maximum(la, lb)[cut]
    pairs, which = np.unique(key, return_inverse=True)
    length = np.bincount(which, weights=dual.length[cut], minlength=len(pairs))
    bent = np.bincount(which, weights=(dual.length * dual.concavity)[cut], minlength=len(pairs))
    return bent / np.maximum(length, 1e-300)


def weakest_boundary(labels: np.ndarray, dual: DualEdges) -> float:
    """The least :func:`boundary_concavity` of ``labels`` [F]: how concave the partition's
    flattest cut is, in [0, 1] (0.05: a boundary bending 9° on average). inf where there is no
    boundary (one part): nothing to prefer."""
    bends = boundary_concavity(labels, dual)
    return float(bends.min()) if len(bends) else float("inf")


def same_partition(labels: np.ndarray, other: np.ndarray) -> bool:
    """Whether two labellings [F] group the faces alike (up to the parts' names)."""
    a, b = np.asarray(labels, dtype=np.int64), np.asarray(other, dtype=np.int64)
    if a.shape != b.shape:
        return False
    if not len(a):
        return True
    pairs = np.unique((a - a.min()) * (int(b.max() - b.min()) + 1) + (b - b.min()))
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def prefers_other(labels: np.ndarray, other: np.ndarray, dual: DualEdges, ratio: float, floor: float) -> bool:
    """Whether partition ``other`` [F] replaces ``labels`` [F] (both of the mesh ``dual``
    describes): its weakest boundary bends more than ``floor`` and more than ``ratio`` times
    that of ``labels``."""
    mine, theirs = weakest_boundary(labels, dual), weakest_boundary(other, dual)
    return bool(np.isfinite(theirs) and theirs > floor and theirs > ratio * mine)


__all__ = ["boundary_concavity", "weakest_boundary", "same_partition", "prefers_other"]
