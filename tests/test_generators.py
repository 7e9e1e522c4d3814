"""Symmetry generators per part (:mod:`torchakvf.parts.generators`) against a masked sum per part."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.partitions import sphere_labels

from torchakvf.mesh.clean import face_areas


def _generators_loop(labels, features, face_area, energies, n_parts, min_share=0.5):
    """part_generators with a masked sum per part."""
    density = features ** 2 * face_area[:, None]
    total = np.maximum(density.sum(axis=0), 1e-300)
    share = np.stack([density[labels == p].sum(axis=0) for p in range(n_parts)]) / total
    out = [[] for _ in range(n_parts)]
    home = share.argmax(axis=0)
    for i in range(features.shape[1]):
        p = int(home[i])
        if share[p, i] >= min_share:
            out[p].append((i, float(share[p, i]), float(energies[i])))
    return [sorted(g, key=lambda t: t[2]) for g in out]


@pytest.mark.parametrize("n_fields", [1, 2, 16])
def test_part_generators_equal_a_masked_sum_per_part(n_fields):
    from torchakvf.parts.generators import part_generators
    v, f, labels = sphere_labels(3, 6, seed=n_fields)
    labels = labels.copy()
    labels[::23] = -1                                                # connecting region
    labels[labels == 5] = 9                                          # beyond n_parts: in no part
    rng = np.random.default_rng(n_fields)
    feats = np.abs(rng.normal(size=(len(f), n_fields))) * (labels[:, None] + 2.0)
    area = face_areas(v, f)
    energies = rng.random(n_fields)
    got = part_generators(labels, feats, area, energies, 5, min_share=0.3)
    ref = _generators_loop(labels, feats, area, energies, 5, min_share=0.3)
    assert [[(g.field, g.share, g.energy) for g in part] for part in got] == ref    # bitwise shares
    assert part_generators(labels, feats, area, energies, 0) == []
