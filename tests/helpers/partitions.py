"""Labelled meshes for the tests of the part clean-up, merging, graph cut and generators."""
from __future__ import annotations

import numpy as np

from torchakvf import shapes


def sphere_labels(level: int, k: int, seed: int):
    """An icosphere's faces cut into k parts by random directions (nearest direction wins):
    vertices [V, 3] float64, faces [F, 3], labels [F] in [0, k)."""
    s = shapes.icosphere(level)
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    rng = np.random.default_rng(seed)
    bary = v[f].mean(1)
    return v, f, np.argmax(bary @ rng.normal(size=(3, k)), axis=1)
