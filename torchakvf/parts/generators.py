"""Prominent symmetry generators of each part: the untangled fields living on it."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .grouping import group_sums


@dataclass(frozen=True)
class SymmetryGenerator:
    """An untangled field localized on a part.

    field : index of the untangled field; share : fraction of its squared norm (∫|X|^2) on
    the part; energy : its Killing energy (λ·area; 0 for an exact isometry).
    """

    field: int
    share: float
    energy: float


def part_generators(labels: np.ndarray, features: np.ndarray, face_area: np.ndarray,
                    energies: np.ndarray, n_parts: int, min_share: float = 0.5
                    ) -> list[list[SymmetryGenerator]]:
    """Per part (0..n_parts-1), the fields with their largest share on it (>= min_share),
    most Killing (lowest energy) first.

    labels : [F] (-1 = connecting region); features : [F, n] |X_f|; face_area : [F]; energies : [n]
    """
    density = features ** 2 * face_area[:, None]                         # ∫|X_i|^2 per face
    total = np.maximum(density.sum(axis=0), 1e-300)
    out: list[list[SymmetryGenerator]] = [[] for _ in range(n_parts)]
    if n_parts == 0:
        return out
    if density.shape[1] > 1:
        # One pass, the faces' rows added in order: a per-part density[labels == p].sum(axis=0)
        # (numpy adds the rows of an [m, n > 1] array one after another) in the same order.
        mine = (labels >= 0) & (labels < n_parts)
        share = (group_sums(labels, density, n_parts) if mine.all()
                 else group_sums(labels[mine], density[mine], n_parts)) / total
    else:
        share = np.stack([density[labels == p].sum(axis=0) for p in range(n_parts)]) / total
    home = share.argmax(axis=0)
    for i in range(features.shape[1]):
        p = int(home[i])
        if share[p, i] >= min_share:
            out[p].append(SymmetryGenerator(i, float(share[p, i]), float(energies[i])))
    for gens in out:
        gens.sort(key=lambda g: g.energy)
    return out
