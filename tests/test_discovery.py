"""Clean-up of small pieces (:mod:`torchakvf.parts.discovery`) against its dict loop written out
here."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.partitions import sphere_labels

from torchakvf.mesh.clean import face_areas
from torchakvf.parts import discovery
from torchakvf.parts.discovery import CONNECTING, remove_small_parts
from torchakvf.parts.topology import face_adjacency, labelled_pieces, piece_neighbours


def _remove_small_parts_loop(labels, adjacency, face_area, min_fraction, into_connecting):
    """The smallest-first loop over pieces with a dict of neighbour counts."""
    out = labels.copy()
    total = face_area.sum()
    n_pieces, piece = labelled_pieces(out, adjacency)
    area = np.bincount(piece, weights=face_area, minlength=n_pieces)
    neighbours = piece_neighbours(piece, out, adjacency)
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
    if into_connecting or min_fraction <= 0:
        return out
    # then, while some piece moves: every small piece left joins the label of the neighbouring
    # pieces that are not small it shares the most edges with (the labels as the pass began)
    moved = True
    while moved:
        moved = False
        n_pieces, piece = labelled_pieces(out, adjacency)
        area = np.bincount(piece, weights=face_area, minlength=n_pieces)
        labels_now = out.copy()
        own = {int(piece[f]): int(labels_now[f]) for f in range(len(out))}
        small = {p for p in range(n_pieces) if area[p] < min_fraction * total and own[p] != CONNECTING}
        counted = np.array([not (piece[a] in small and piece[b] in small) for a, b in adjacency], dtype=bool)
        neighbours = piece_neighbours(piece, labels_now, adjacency[counted])
        for p in sorted(small):
            cand = {lab: c for lab, c in neighbours.get(p, {}).items() if lab != CONNECTING}
            if cand:
                out[piece == p] = max(cand, key=cand.get)
                moved = True
    return out


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("into_connecting", [False, True])
def test_remove_small_parts_equals_the_loop(seed, into_connecting):
    v, f, labels = sphere_labels(3, 6, seed)
    rng = np.random.default_rng(seed)
    noisy = labels.copy()
    flip = rng.random(len(noisy)) < 0.08                             # islands of one face or a few
    noisy[flip] = rng.integers(-1, 6, int(flip.sum()))
    adjacency = face_adjacency(f)
    area = face_areas(v, f)
    for frac in (0.0, 0.001, 0.01, 0.2, 1.5):
        np.testing.assert_array_equal(remove_small_parts(noisy, adjacency, area, frac, into_connecting),
                                      _remove_small_parts_loop(noisy, adjacency, area, frac, into_connecting))


def test_remove_small_parts_leaves_no_small_piece_beside_a_large_one():
    """A strip: two one-face pieces side by side (labels 7, 8) between two large parts, each
    sharing two edges with the other (listed twice) and one with its large neighbour. The
    first pass swaps their labels, so both are still small; the further passes move each into
    the large part beside it."""
    labels = np.array([1, 1, 1, 1, 7, 8, 2, 2, 2, 2])
    # face 4 shares 2 edges with face 5 (a fan) and 1 with face 3; face 5 likewise with 6
    adjacency = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [4, 5], [5, 6], [6, 7], [7, 8], [8, 9]])
    area = np.ones(10)
    out = remove_small_parts(labels, adjacency, area, 0.15, False)
    np.testing.assert_array_equal(out, _remove_small_parts_loop(labels, adjacency, area, 0.15, False))
    assert set(out.tolist()) == {1, 2} and out[4] == 1 and out[5] == 2
    n, piece = labelled_pieces(out, adjacency)
    assert np.bincount(piece).min() >= 2
    # one pass alone (part discovery's rule) swaps them and stops
    first, _ = discovery.small_pieces_pass(labels, adjacency, area, 1.5, False, False)
    np.testing.assert_array_equal(first[4:6], [8, 7])


def test_remove_small_parts_breaks_ties_as_the_dict_does():
    # A strip of unit faces: a one-face piece between two labels, one shared edge each; the
    # label met first in piece_neighbours' order wins, whichever id is smaller.
    for left, right in ((3, 1), (1, 3)):
        labels = np.array([left, left, left, 7, right, right, right])
        adjacency = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6]])
        area = np.ones(7)
        np.testing.assert_array_equal(remove_small_parts(labels, adjacency, area, 0.2, False),
                                      _remove_small_parts_loop(labels, adjacency, area, 0.2, False))
        adjacency = adjacency[::-1]
        np.testing.assert_array_equal(remove_small_parts(labels, adjacency, area, 0.2, False),
                                      _remove_small_parts_loop(labels, adjacency, area, 0.2, False))
