"""Rays cast on a mesh at any unit of length: libigl's AABB tree (MPL-2.0) in a frame scaled by a
power of two.

libigl's ray-triangle test (Möller & Trumbore) compares a determinant with a fixed 1e-6; the
determinant is the product of two edge lengths and the ray direction's length, so where the
faces are small in the mesh's units (a part modelled in metres, a fine scan) a ray passes through
faces it crosses: on a chair 0.11 across, every line of sight between its parts came out clear
and no thickness ray hit. :class:`RayCaster` casts in the mesh scaled by the power of two that
brings its mean edge length into [2^-1/2, 2^1/2): every copy of a shape, whatever its unit,
casts the same rays, and a power of two changes no mantissa (the same hits and parameters, up
to those the fixed threshold decided).
"""
from __future__ import annotations

import numpy as np


def ray_scale(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The power of two s with s · (mean edge length) in [2^-1/2, 2^1/2) (1.0 without a
    non-degenerate edge). vertices : [V, 3]; faces : [F, 3]."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 1.0
    edges = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)
    mean = float(edges.mean())
    if not np.isfinite(mean) or mean <= 0.0:
        return 1.0
    return float(2.0 ** -np.round(np.log2(mean)))


class RayCaster:
    """A mesh's ray-casting tree (made once, read for any number of rays).

    vertices : [V, 3]; faces : [F, 3]. Rays and parameters are in the mesh's own units; the
    tree holds the mesh scaled by :func:`ray_scale`."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import igl

        self.scale = ray_scale(vertices, faces)
        self.vertices = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64) * self.scale)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.tree = igl.AABB()
        if len(self.faces):
            self.tree.init(self.vertices, self.faces)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray,
                  max_t: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """(face [N] int64, t [N]) of the first face each ray origins + t · directions (t >= 0)
        crosses: the face id, -1 where none does (or none before ``max_t``, which bounds the
        search); t in units of the direction given (a distance for unit directions), inf where
        no face was hit. origins, directions : [N, 3]."""
        n = len(origins)
        face, t = np.full(n, -1, dtype=np.int64), np.full(n, np.inf)
        if n == 0 or len(self.faces) == 0:
            return face, t
        directions = np.asarray(directions, dtype=np.float64)
        length = np.linalg.norm(directions, axis=1) * self.scale
        ok = length > 0                     # a ray without a direction crosses nothing
        if not ok.any():
            return face, t
        # The determinant also scales with the direction's length: directions shorter than
        # about an edge (a unit ray on a mesh 1e9 across) are lengthened by one power of two
        # for all rays, so one bound still serves every ray and no mantissa changes.
        shortest = float(length[ok].min())
        c = 2.0 ** np.ceil(-np.log2(shortest)) if shortest < 1.0 else 1.0
        o = np.ascontiguousarray(np.asarray(origins, dtype=np.float64)[ok] * self.scale)
        d = np.ascontiguousarray(directions[ok] * (self.scale * c))
        hit, t_scaled, _ = self.tree.intersect_ray_first(self.vertices, self.faces, o, d, min_t=float(max_t) / c)
        t_given = np.asarray(t_scaled, dtype=np.float64) * c
        # the bound prunes the search; a hit at or past it is not one
        hit = np.where(t_given < max_t, np.asarray(hit, dtype=np.int64), -1)
        face[ok] = hit
        t[ok] = np.where(hit >= 0, t_given, np.inf)
        return face, t


__all__ = ["RayCaster", "ray_scale"]
