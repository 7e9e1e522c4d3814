"""How open to the outside a face is, and the concave bending that lies hidden from it.

The minima rule says people cut along concave creases, but not along every one: the crease at the
bottom of a blind hole (a pipe fitting's socket, a bored hub, the inside of a cup or a vase) is
where the hole ends, not where a part does. Such a crease lies inside a cavity: little of the sky
is seen from it. A face's openness is the share of :data:`OPEN_RAYS` rays, spread evenly over the
hemisphere around its outward normal, that travel :data:`OPEN_REACH` of the surface's size
(the square root of its area) without crossing a face. A concave dual edge bending more than
:data:`HIDDEN_BEND` is hidden by 1 - min(1, o / :data:`OPEN_ENOUGH`), o the mean openness of its
two faces: a 90° corner in the open (each face sees half its sky) counts as open, a socket's
bottom as hidden. The merge reads the hidden share of a boundary's concave bending as a term of
its own (``hidden_concavity``, :mod:`torchakvf.parts.merge_terms`), whose learned weight cancels
the concavity term where the crease is hidden (docs/design.md, "Hidden creases").

Rays are cast only from faces on a concave boundary the merge reads, when it first reads one
(:class:`FaceOpenness` keeps what it cast), on libigl's AABB tree at any unit of length
(:class:`~torchakvf.mesh.raycast.RayCaster`, shared with the lines of sight where they are
cast). Rays go in a fixed frame of each face (:func:`hemisphere_directions`), so a moved or
renumbered copy of a mesh gets the same openness up to the frame's choice of tangent directions.
"""
from __future__ import annotations

import math

import numpy as np

from ..mesh.clean import face_cross_products
from ..mesh.raycast import RayCaster
from .concavity import DualEdges
from .creases import unit_face_normals

#: rays cast per face: the openness is a multiple of 1/16
OPEN_RAYS = 16
#: how far a ray must travel free, relative to the square root of the surface area
OPEN_REACH = 0.25
#: concave bending (radians) above which a dual edge's crease can be hidden; flatter edges
#: weigh little in the concavity term and are not cast from
HIDDEN_BEND = math.radians(10.0)
#: openness at and above which a crease counts as fully open (a face at a 90° corner in the
#: open sees half of its hemisphere)
OPEN_ENOUGH = 0.5


def hemisphere_directions(n_rays: int) -> np.ndarray:
    """[n_rays, 3] fixed unit directions spread evenly (in solid angle) over the hemisphere
    around +z, on a golden-angle spiral from the pole down to the horizon."""
    i = np.arange(n_rays) + 0.5
    cos_t = 1.0 - i / n_rays
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


class FaceOpenness:
    """A mesh's faces' openness (:func:`of`), cast for the faces asked for and kept.

    vertices : [V, 3]; faces : [F, 3] outward-oriented (counter-clockwise from outside);
    caster : the mesh's :class:`~torchakvf.mesh.raycast.RayCaster` if at hand."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, caster: RayCaster | None = None):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.caster = caster
        self.known = np.full(len(self.faces), np.nan)
        area = 0.5 * float(np.linalg.norm(face_cross_products(self.vertices, self.faces), axis=1).sum())
        self.size = math.sqrt(area) if area > 0 else 1.0

    def of(self, face_ids: np.ndarray) -> np.ndarray:
        """[n] openness in [0, 1] of faces ``face_ids`` [n]: the share of the hemisphere rays
        from the face's centroid that travel ``OPEN_REACH`` sqrt(area) without crossing a face
        (a degenerate face, without a normal, counts as open)."""
        face_ids = np.asarray(face_ids, dtype=np.int64)
        todo = np.unique(face_ids[np.isnan(self.known[face_ids])])
        if len(todo):
            self.known[todo] = self._cast(todo)
        return self.known[face_ids]

    def _cast(self, ids: np.ndarray) -> np.ndarray:
        normal = unit_face_normals(self.vertices, self.faces[ids])
        ok = np.linalg.norm(normal, axis=1) > 0
        out = np.ones(len(ids))
        if not ok.any():
            return out
        n = normal[ok]
        # an orthonormal frame (t1, t2, n) per face, from the axis least along the normal's
        helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(n, t1)
        h = hemisphere_directions(OPEN_RAYS)
        dirs = (h[None, :, 0:1] * t1[:, None] + h[None, :, 1:2] * t2[:, None]
                + h[None, :, 2:3] * n[:, None]).reshape(-1, 3)
        centroid = self.vertices[self.faces[ids[ok]]].mean(axis=1)
        # off the face by a hair, so that it does not hit itself
        origin = np.repeat(centroid, OPEN_RAYS, axis=0) + 1e-6 * self.size * dirs
        if self.caster is None:
            self.caster = RayCaster(self.vertices, self.faces)
        _, t = self.caster.first_hit(origin, dirs, max_t=OPEN_REACH * self.size)
        out[ok] = (~np.isfinite(t)).reshape(-1, OPEN_RAYS).mean(axis=1)
        return out

    def hidden_bends(self, dual: DualEdges, concave_bends: np.ndarray, edges: np.ndarray) -> np.ndarray:
        """[P] each dual edge's concave bending weight ``concave_bends`` [P] (length x concave
        weight, :func:`~torchakvf.parts.merge.boundary_bends`) times its hidden share, on the
        edges selected by the bool mask ``edges`` [P] (0 elsewhere): rays are cast only from the
        faces of selected edges bending more than :data:`HIDDEN_BEND`."""
        out = np.zeros(len(dual.length))
        sel = np.flatnonzero(np.asarray(edges) & (dual.dihedral > HIDDEN_BEND))
        if len(sel) == 0:
            return out
        a, b = dual.pairs[sel, 0], dual.pairs[sel, 1]
        seen = 0.5 * (self.of(a) + self.of(b))
        out[sel] = concave_bends[sel] * (1.0 - np.minimum(1.0, seen / OPEN_ENOUGH))
        return out


__all__ = ["OPEN_RAYS", "OPEN_REACH", "HIDDEN_BEND", "OPEN_ENOUGH", "hemisphere_directions", "FaceOpenness"]
