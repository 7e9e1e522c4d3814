"""Planar meshes (+z normals): a flat disk and a jittered square patch (open-mesh oracles)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from .revolution import ring_counts
from .shape import ROW_HEIGHT, Shape


def _planar_delaunay(xy: np.ndarray):
    """Delaunay triangulation of 2-D points, embedded at z = 0 with normals along +z."""
    faces = Delaunay(xy).simplices.astype(np.int64)
    e1 = xy[faces[:, 1]] - xy[faces[:, 0]]
    e2 = xy[faces[:, 2]] - xy[faces[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    faces[clockwise] = faces[clockwise][:, ::-1]
    return np.column_stack([xy, np.zeros(len(xy))]), faces


def flat_disk(radius: float = 1.0, n_boundary: int = 84) -> Shape:
    """Planar disk at z = 0: Delaunay triangulation of concentric rings of points.

    Rings are spaced ``sqrt(3)/2`` times the boundary spacing apart, each with about
    circumference/spacing points (a multiple of 6), staggered ring to ring, plus the
    centre: near-equilateral triangles throughout.

    Parameters
    ----------
    radius : float
        Disk radius (length units).
    n_boundary : int
        Points on the boundary circle (rounded to a multiple of 6); defaults give
        about 1300 faces.

    Returns
    -------
    Shape
        Open disk-like mesh (Euler characteristic 1) with normals along +z.
    """
    edge = 2 * np.pi * radius / n_boundary
    n_rings = max(1, round(radius / (ROW_HEIGHT * edge)))
    ring_r = radius * np.arange(1, n_rings + 1) / n_rings
    points = [np.zeros((1, 2))]
    for i, (rho, n) in enumerate(zip(ring_r, ring_counts(ring_r, edge))):
        angle = (2 * np.arange(n) + i % 2) * np.pi / n
        points.append(rho * np.column_stack([np.cos(angle), np.sin(angle)]))
    vertices, faces = _planar_delaunay(np.vstack(points))
    return Shape("flat_disk", vertices, faces)


def square_patch(n: int = 24, jitter: float = 0.2, seed: int = 0) -> Shape:
    """Planar unit square ``[0, 1]^2`` at z = 0: Delaunay triangulation of a jittered grid.

    Parameters
    ----------
    n : int
        Grid points per side (``n * n`` vertices, ``2 (n - 1)^2`` faces; default 1058).
    jitter : float
        Interior points move uniformly by up to ``jitter`` grid spacings along x and y;
        boundary points stay put so the boundary is the exact square.
    seed : int
        Seed for ``np.random.default_rng``.

    Returns
    -------
    Shape
        Open disk-like mesh (Euler characteristic 1) with normals along +z.
    """
    spacing = 1.0 / (n - 1)
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="xy")
    xy = np.column_stack([x.ravel(), y.ravel()])
    interior = np.all((xy > spacing / 2) & (xy < 1 - spacing / 2), axis=1)
    rng = np.random.default_rng(seed)
    xy[interior] += rng.uniform(-jitter, jitter, size=(interior.sum(), 2)) * spacing
    vertices, faces = _planar_delaunay(xy)
    return Shape("square_patch", vertices, faces)
