"""Face adjacency and connected pieces (:mod:`torchakvf.parts.topology`)."""
from __future__ import annotations

import numpy as np
from helpers.partitions import sphere_labels

from torchakvf.parts.discovery import CONNECTING
from torchakvf.parts.topology import face_adjacency, labelled_pieces, piece_label_counts, piece_neighbours


def test_piece_label_counts_are_piece_neighbours():
    v, f, labels = sphere_labels(3, 8, seed=5)
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
