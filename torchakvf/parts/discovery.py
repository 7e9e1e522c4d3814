"""Part discovery (ε > 0): the asymmetric connecting region between symmetric parts, and
clean-up of the labels (Sec. 5 of the paper)."""
from __future__ import annotations

import numpy as np

from .topology import labelled_pieces, piece_neighbours

CONNECTING = -1


def connecting_region(labels: np.ndarray, margins: np.ndarray, eps: float) -> np.ndarray:
    """Faces whose barycenter lies between the +ε and -ε isolines of their two closest parts
    (margin < ε) become the connecting region (label -1)."""
    out = labels.copy()
    out[margins < eps] = CONNECTING
    return out


def absorb_single_neighbour_regions(labels: np.ndarray, adjacency: np.ndarray) -> np.ndarray:
    """Pieces of the connecting region that border a single part join that part: they connect nothing."""
    out = labels.copy()
    n_pieces, piece = labelled_pieces(out, adjacency)
    neighbours = piece_neighbours(piece, out, adjacency)
    for p in range(n_pieces):
        faces = piece == p
        if out[faces][0] != CONNECTING:
            continue
        parts = {lab for lab in neighbours.get(p, {}) if lab != CONNECTING}
        if len(parts) == 1:
            out[faces] = parts.pop()
    return out


def remove_small_parts(labels: np.ndarray, adjacency: np.ndarray, face_area: np.ndarray,
                       min_fraction: float, into_connecting: bool) -> np.ndarray:
    """Connected pieces of a part with less than ``min_fraction`` of the area are removed.

    into_connecting=True (part discovery): they become connecting region.
    into_connecting=False (segmentation): they join the neighbouring label they share the
    most edges with (a stray island of one cluster inside another is noise, not a part).
    """
    if min_fraction <= 0:
        return labels
    out = labels.copy()
    total = face_area.sum()
    n_pieces, piece = labelled_pieces(out, adjacency)
    area = np.bincount(piece, weights=face_area, minlength=n_pieces)
    neighbours = piece_neighbours(piece, out, adjacency)
    # Smallest first, so a small piece can join a neighbour that itself survives.
    for p in np.argsort(area):
        if area[p] >= min_fraction * total:
            break
        faces = piece == p
        if out[faces][0] == CONNECTING:
            continue
        if into_connecting:
            out[faces] = CONNECTING
            continue
        cand = {lab: c for lab, c in neighbours.get(int(p), {}).items() if lab != CONNECTING}
        if cand:
            out[faces] = max(cand, key=cand.get)
    return out
