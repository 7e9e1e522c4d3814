"""Face adjacency and connected pieces (:mod:`torchakvf.parts.topology`)."""
from __future__ import annotations

import numpy as np

from torchakvf import shapes
from torchakvf.parts.discovery import CONNECTING
from torchakvf.parts.topology import face_adjacency, labelled_pieces, piece_label_counts, piece_neighbours


def _sphere_labels(level: int, k: int, seed: int):
    """An icosphere's faces cut into k parts by random directions (nearest direction wins)."""
    s = shapes.icosphere(level)
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    rng = np.random.default_rng(seed)
    bary = v[f].mean(1)
    return v, f, np.argmax(bary @ rng.normal(size=(3, k)), axis=1)


def test_piece_label_counts_are_piece_neighbours():
    v, f, labels = _sphere_labels(3, 8, seed=5)
    labels = labels.copy()
    labels[::17] = CONNECTING
    adjacency = face_adjacency(f)
    _, piece = labelled_pieces(labels, adjacency)
    p, lab, count, first = piece_label_counts(piece, labels, adjacency)
    ref = piece_neighbours(piece, labels, adjacency)
    assert {(int(a), int(b)): int(c) for a, b, c in zip(p, lab, count)} == \
           {(a, b): c for a, d in ref.items() for b, c in d.items()}
    for a, d in ref.items():                                         # dict order = order of first
        mine = [int(b) for b in lab[p == a][np.argsort(first[p == a])]]
        assert mine == list(d)
