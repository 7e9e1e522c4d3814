"""Framing: the orthographic camera that shows a mesh best.

The mesh is put on its principal axes (PCA of the area-weighted face centroids), and the camera
looks from the oblique direction, among a few around each principal axis, that shows the largest
projected area (``0.5 Σ A_f |n_f · d|``), with the longest visible principal axis horizontal. Of
the two opposite directions it looks from the side the area lies toward, and turns the picture
upright (most of the area above the middle). A reclining human is seen from above at full length,
a table from above at an angle rather than edge-on, a four-legged animal standing on its legs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...mesh.clean import face_cross_products


@dataclass(frozen=True)
class View:
    """An orthographic camera: ``rotation`` [3, 3] rows (right, up, toward viewer) applied to
    ``vertices - center``."""

    rotation: np.ndarray
    center: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """[N, 3] camera coordinates of world points [N, 3] (z toward the viewer)."""
        return (np.asarray(points, float) - self.center) @ self.rotation.T


def face_geometry(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centroids [F, 3], unit normals [F, 3], areas [F]) of the faces f [F, 3] of vertices v [V, 3]."""
    tri = v[f]
    n = face_cross_products(v, f)
    area2 = np.linalg.norm(n, axis=1)
    return tri.mean(axis=1), n / np.maximum(area2, 1e-300)[:, None], 0.5 * area2


def principal_axes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(center [3], axes [3, 3]): the area-weighted centroid and the principal axes of the
    surface (rows, largest extent first), from the area-weighted covariance of the face
    centroids (vertex density does not bias it)."""
    c, _, a = face_geometry(np.asarray(vertices, float), np.asarray(faces))
    return _principal_axes(c, a)


def _principal_axes(c: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_axes` from the face centroids c [F, 3] and areas a [F]."""
    w = a / max(a.sum(), 1e-300)
    center = w @ c
    d = c - center
    cov = (d * w[:, None]).T @ d
    _, vecs = np.linalg.eigh(cov)
    axes = vecs[:, ::-1].T.copy()
    if np.linalg.det(axes) < 0:
        axes[2] *= -1
    return center, axes


def projected_area(normals: np.ndarray, areas: np.ndarray, direction: np.ndarray) -> float:
    """Silhouette area of a closed surface seen along ``direction``: ``0.5 Σ A_f |n_f · d|``."""
    return 0.5 * float(areas @ np.abs(normals @ direction))


def best_view(vertices: np.ndarray, faces: np.ndarray, tilt: float = 0.4) -> View:
    """The oblique view (``tilt`` toward the two other axes) around a principal axis that
    shows the largest projected area; the longest principal axis visible across the picture
    is horizontal."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    cent, normals, areas = face_geometry(v, f)
    center, axes = _principal_axes(cent, areas)
    best = None
    for i in range(3):
        j, k = [a for a in range(3) if a != i]
        for sj in (1, -1):
            for sk in (1, -1):
                d = axes[i] + tilt * (sj * axes[j] + sk * axes[k])
                d /= np.linalg.norm(d)
                score = projected_area(normals, areas, d)
                if best is None or score > best[0] * (1 + 1e-9):
                    best = (score, d, j)
    _, d, j = best
    # d and -d show the same area; look from the side the surface's area lies toward (a
    # table from above its top, not from under its legs)
    bulk = (areas @ cent) / max(areas.sum(), 1e-300)
    mid = 0.5 * ((cent @ d).max() + (cent @ d).min())
    if bulk @ d < mid:
        d = -d
    right = axes[j] - (axes[j] @ d) * d               # longest axis not looked along, in the image plane
    right /= np.linalg.norm(right)
    up = np.cross(d, right)
    # upright: the bulk of the area above the middle, thin protrusions (legs) below; turning
    # the picture half a turn about the view direction keeps the camera a rotation
    h = cent @ up
    if bulk @ up < 0.5 * (h.max() + h.min()):
        right, up = -right, -up
    return View(np.stack([right, up, d]), center)


def opposite_view(view: View) -> View:
    """The same framing seen from behind (turned about the vertical image axis)."""
    r = view.rotation
    return View(np.stack([-r[0], r[1], -r[2]]), view.center)


def view_aspect(vertices, view: View) -> float:
    """Height / width of the mesh's picture in this view, clamped to [0.3, 1] (landscape)."""
    p = view.apply(np.asarray(vertices, float))
    ext = np.ptp(p[:, :2], axis=0)
    return float(np.clip(ext[1] / max(ext[0], 1e-12), 0.3, 1.0))


__all__ = ["View", "face_geometry", "principal_axes", "projected_area", "best_view", "opposite_view",
           "view_aspect"]
