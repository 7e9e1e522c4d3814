"""Subdivided icosahedra: spheres, ellipsoids and the hemisphere (eigenvalue oracles)."""
from __future__ import annotations

import numpy as np

from .shape import Shape


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit icosahedron with a vertex on each pole of the z axis, faces outward.

    This orientation (rather than the usual one with coordinate mirror planes) leaves no
    face symmetric about z = 0, so :func:`hemisphere`'s centroid test never sees a tie.
    """
    k = np.arange(5)
    z_ring, r_ring = 1.0 / np.sqrt(5.0), 2.0 / np.sqrt(5.0)
    upper = np.column_stack([r_ring * np.cos(2 * np.pi * k / 5),
                             r_ring * np.sin(2 * np.pi * k / 5), np.full(5, z_ring)])
    lower = np.column_stack([r_ring * np.cos(2 * np.pi * (k + 0.5) / 5),
                             r_ring * np.sin(2 * np.pi * (k + 0.5) / 5), np.full(5, -z_ring)])
    vertices = np.vstack([[0.0, 0.0, 1.0], upper, lower, [0.0, 0.0, -1.0]])
    u, w = 1 + k, 1 + (k + 1) % 5           # consecutive upper-ring vertices
    lo, lo_next = 6 + k, 6 + (k + 1) % 5    # lower-ring vertex between them, and the next
    faces = np.vstack([
        np.column_stack([np.zeros(5, int), u, w]),     # top cap
        np.column_stack([u, lo, w]),                   # band, pointing down
        np.column_stack([w, lo, lo_next]),             # band, pointing up
        np.column_stack([np.full(5, 11), lo_next, lo]),  # bottom cap
    ])
    return vertices, faces.astype(np.int64)


def _subdivide_on_sphere(vertices: np.ndarray, faces: np.ndarray):
    """Split every triangle into 4 at its edge midpoints, pushed onto the unit sphere."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    midpoints = vertices[unique].mean(axis=1)
    midpoints /= np.linalg.norm(midpoints, axis=1, keepdims=True)
    m01, m12, m20 = (inverse.reshape(-1, 3) + len(vertices)).T
    a, b, c = faces.T
    new_faces = np.vstack([np.column_stack([a, m01, m20]), np.column_stack([b, m12, m01]),
                           np.column_stack([c, m20, m12]), np.column_stack([m01, m12, m20])])
    return np.vstack([vertices, midpoints]), new_faces


def icosphere(level: int = 3, radius: float = 1.0) -> Shape:
    """Subdivided icosahedron projected onto a sphere.

    Parameters
    ----------
    level : int
        Number of 1-to-4 subdivisions: ``20 * 4**level`` faces, ``30 * 4**level`` edges,
        ``10 * 4**level + 2`` vertices (level 3: 1280 faces; level 4: 5120 faces).
    radius : float
        Sphere radius (length units).

    Returns
    -------
    Shape
        Closed genus-0 mesh centred at the origin, with a vertex on each pole.
    """
    vertices, faces = _icosahedron()
    for _ in range(level):                 # each child keeps its parent's orientation
        vertices, faces = _subdivide_on_sphere(vertices, faces)
    return Shape("icosphere", radius * vertices, faces.astype(np.int64))


def ellipsoid(axes: tuple[float, float, float] = (1.0, 1.3, 1.7), level: int = 4) -> Shape:
    """Icosphere scaled along x, y, z into a triaxial ellipsoid.

    Parameters
    ----------
    axes : (3,) floats
        Semi-axes along x, y, z (length units).
    level : int
        Icosphere subdivision level (level 4: 5120 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh centred at the origin.
    """
    sphere = icosphere(level)
    return Shape("ellipsoid", sphere.vertices * np.asarray(axes, dtype=np.float64), sphere.faces)


def hemisphere(level: int = 4) -> Shape:
    """Upper half (faces with centroid z > 0) of the unit ``icosphere(level)``.

    Parameters
    ----------
    level : int
        Subdivision level of the sphere it is cut from (level 4: 2560 faces).

    Returns
    -------
    Shape
        Open disk-like mesh (one boundary loop near z = 0), unreferenced vertices removed.
    """
    sphere = icosphere(level)
    keep = sphere.vertices[sphere.faces, 2].mean(axis=1) > 0
    used, faces = np.unique(sphere.faces[keep], return_inverse=True)
    return Shape("hemisphere", sphere.vertices[used], faces.reshape(-1, 3).astype(np.int64))
