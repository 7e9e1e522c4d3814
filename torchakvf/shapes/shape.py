"""The :class:`Shape` record every generator returns, and the ring conventions they share."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Ring vertex counts are multiples of this: exact 6-fold symmetry about z, and the ring
#: next to a pole is a hexagon whose fan triangles are near-equilateral.
RING_SYMMETRY = 6
#: Height of an equilateral triangle with unit edge: the profile arc-length step per unit
#: of target edge length.
ROW_HEIGHT = np.sqrt(3.0) / 2.0


@dataclass(eq=False)  # array fields: the generated element-wise __eq__ would be ambiguous
class Shape:
    """A named triangle mesh with optional ground-truth part labels.

    Attributes
    ----------
    name : str
        Short identifier (the key in :data:`BUILTIN_SHAPES` for composite shapes).
    vertices : np.ndarray, shape (V, 3), float64
        Vertex positions.
    faces : np.ndarray, shape (F, 3), int64
        0-based vertex indices, counter-clockwise seen from outside.
    part_labels : np.ndarray, shape (F,), int64, or None
        Ground-truth part of each face, in ``0 .. n_parts - 1``; None for one-part shapes.
    n_parts : int
        Number of ground-truth parts (1 for shapes without labels).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    part_labels: np.ndarray | None = None
    n_parts: int = 1
