"""Rays cast on a mesh at any unit of length: libigl's AABB tree (MPL-2.0) in a frame scaled by a
power of two; segments tested for a crossing by Embree (Apache-2.0) where it is installed.

libigl's ray-triangle test (Möller & Trumbore) compares a determinant with a fixed 1e-6; the
determinant is the product of two edge lengths and the ray direction's length, so where the
faces are small in the mesh's units (a part modelled in metres, a fine scan) a ray passes through
faces it crosses: on a chair 0.11 across, every line of sight between its parts came out clear
and no thickness ray hit. :class:`RayCaster` casts in the mesh scaled by the power of two that
brings its mean edge length into [2^-1/2, 2^1/2): every copy of a shape, whatever its unit,
casts the same rays, and a power of two changes no mantissa (the same hits and parameters, up
to those the fixed threshold decided).

Whether a segment crosses any face (:meth:`RayCaster.blocked`, the lines of sight's only
question) needs no first hit: Embree's occlusion query (through ``embreex``, the binding trimesh
uses; BSD) stops at any face before the far end, and its BVH traversal is several times faster
than the AABB tree's search for the nearest face (5-9x less CPU for the segments of 40 parts on
PSB meshes). Embree works in float32 (the mesh moved to its bounding box's centre first), the tree
in float64. The lines of sight's endpoints lie a ten-thousandth of the bounding-box diagonal
inside the surface, about a thousand float32 steps of the coordinates; a segment that grazes an
edge or a vertex on its way, where the tree's fixed threshold lets some pass and Embree's
watertight test (its robust mode) does not, is where the two could differ. On the whole PSB's
eval they did not change one prediction; ``tests/test_raycast.py`` compares them. ``embreex``
publishes wheels for x86-64 Linux and Windows only; elsewhere the tree answers
(``engine="libigl"``).
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from ..errors import ParameterError

#: what :meth:`RayCaster.blocked` tests segments with: "auto" (Embree where ``embreex`` imports,
#: else libigl), "embree", "libigl"
ENGINES = ("auto", "embree", "libigl")


def embree_available() -> bool:
    """Whether Embree's binding (``embreex``) imports here."""
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


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
    """A mesh's ray-casting trees (each made once, on first use; read for any number of rays).

    vertices : [V, 3]; faces : [F, 3]. Rays and parameters are in the mesh's own units; the
    tree holds the mesh scaled by :func:`ray_scale`. engine : what :meth:`blocked` tests
    segments with (:data:`ENGINES`); ``engine`` is the one it uses ("embree" or "libigl")."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, engine: str = "auto"):
        if engine not in ENGINES:
            raise ParameterError(f"engine must be one of {ENGINES}, got {engine!r}")
        embree = engine != "libigl" and embree_available()
        if engine == "embree" and not embree:
            raise ParameterError("engine 'embree' needs the embreex package (pip install embreex; wheels for "
                                 "x86-64 Linux and Windows), or use engine 'libigl'")
        self.engine = "embree" if embree else "libigl"
        self.scale = ray_scale(vertices, faces)
        self.vertices = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64) * self.scale)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)

    @cached_property
    def tree(self):
        """libigl's AABB tree of the scaled mesh, built on first use: a caster whose segments
        Embree tests and that casts no ray never needs it."""
        import igl

        tree = igl.AABB()
        if len(self.faces):
            tree.init(self.vertices, self.faces)
        return tree

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

    def blocked(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """[N] bool: whether the segment from each origin to origin + direction (t in [0, 1))
        crosses a face. origins, directions : [N, 3] in the mesh's units; a segment of zero
        length crosses nothing."""
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(origins), dtype=bool)
        if len(origins) == 0 or len(self.faces) == 0:
            return out
        if self.engine == "libigl":
            _, t = self.first_hit(origins, directions, max_t=1.0)
            return t < 1.0
        ok = np.linalg.norm(directions, axis=1) > 0
        if not ok.any():
            return out
        center, scene, _ = self._embree
        o = np.ascontiguousarray(origins[ok] * self.scale - center, dtype=np.float32)
        d = np.ascontiguousarray(directions[ok] * self.scale, dtype=np.float32)
        hit = scene.run(o, d, dists=1.0, query="OCCLUDED")
        out[ok] = np.asarray(hit) >= 0
        return out

    @cached_property
    def _embree(self):
        """(center [3], Embree scene of the scaled mesh moved to ``center`` = 0, the geometry
        that scene holds, kept with it), built on first use. The move keeps the float32
        coordinates' round-off at the scale of an edge, not of the mesh's distance from its
        origin."""
        from embreex.mesh_construction import TriangleMesh
        from embreex.rtcore_scene import EmbreeScene

        center = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        scene = EmbreeScene(robust=True)
        mesh = TriangleMesh(scene, np.ascontiguousarray(self.vertices - center, dtype=np.float32),
                            np.ascontiguousarray(self.faces, dtype=np.int32))
        return center, scene, mesh


__all__ = ["ENGINES", "RayCaster", "embree_available", "ray_scale"]
