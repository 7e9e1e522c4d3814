"""Part ids and sums by part (:mod:`torchakvf.parts.grouping`) against np.unique and np.add.at,
bitwise."""
from __future__ import annotations

import numpy as np

from torchakvf.parts.grouping import compact_labels, group_sums


def test_compact_labels_and_group_sums_are_unique_and_add_at():
    rng = np.random.default_rng(0)
    labels = rng.choice([-1, 0, 3, 4, 9], size=500)
    out, k = compact_labels(labels)
    uniq, inv = np.unique(labels[labels >= 0], return_inverse=True)
    assert k == len(uniq)
    np.testing.assert_array_equal(out[labels >= 0], inv)
    assert (out[labels < 0] == -1).all()
    rows = rng.normal(size=(len(inv), 7))
    ref = np.zeros((k, 7))
    np.add.at(ref, inv, rows)
    np.testing.assert_array_equal(group_sums(inv, rows, k), ref)      # bitwise
    assert compact_labels(np.full(4, -1))[1] == 0


def test_group_sums_is_add_at_bitwise():
    rng = np.random.default_rng(0)
    for n, m, groups in ((1, 1, 1), (7, 1, 3), (500, 5, 9), (3000, 32, 40)):
        g = rng.integers(0, groups, n)
        rows = rng.normal(size=(n, m)) * rng.choice([1e-8, 1.0, 1e8], size=(n, 1))
        ref = np.zeros((groups, m))
        np.add.at(ref, g, rows)
        np.testing.assert_array_equal(group_sums(g, rows, groups), ref)
        # and the per-part boolean-mask sums a loop over parts would take
        loop = np.stack([rows[g == p].sum(axis=0) if (g == p).any() else np.zeros(m) for p in range(groups)])
        if m > 1:                      # (one column: numpy sums pairwise, not row by row)
            np.testing.assert_array_equal(group_sums(g, rows, groups), loop)
    assert group_sums(np.zeros(0, dtype=int), np.zeros((0, 3)), 4).shape == (4, 3)
    np.testing.assert_array_equal(group_sums(np.array([2, 2]), np.ones((2, 2)), 3), [[0, 0], [0, 0], [2, 2]])
