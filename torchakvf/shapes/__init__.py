"""Built-in triangle meshes generated in code (numpy and scipy; libigl's marching cubes for the
procedural shapes), one module a family:
:mod:`.shape` (the record), :mod:`.icosphere`, :mod:`.revolution`, :mod:`.planar`,
:mod:`.composites` (known parts), :mod:`.implicit` (a table, a mug, a four-legged animal
and a fish: voxel and level-set surfaces with known parts) and :mod:`.deformations`; and the
procedural corpus of part-labelled shapes drawn from seeds, :mod:`.procedural` (families in
:mod:`.mechanical` and :mod:`.organic`, solids in :mod:`.sdf`, meshing in :mod:`.marching`).

They serve three purposes:

1. test oracles for eigenvalue tables of the discrete Killing operator (spheres,
   ellipsoids, tori, tubes, flat patches, ...);
2. composite shapes with *known* parts (blobs joined by thin necks, disconnected tori)
   for segmentation tests and the demo, with a ground-truth label per face;
3. training and selection data with exact parts, the procedural corpus (imported as
   ``torchakvf.shapes.procedural``, not here: its families load on demand).

Conventions for every mesh: faces are counter-clockwise seen from outside (outward
normals; +z for the planar ones), the mesh is manifold, and it has no duplicate vertices
and no degenerate faces.  Lengths are in arbitrary units (the unit sphere has radius 1).

Triangle quality drives the accuracy and conditioning of the operator, so surfaces of
revolution are built ring by ring with near-equilateral triangles of one target edge
length: rings are spaced sqrt(3)/2 edge apart in arc length along the profile, each ring
gets about circumference/edge vertices, consecutive rings are staggered by half a step,
and a pole is closed by a fan over a 6-vertex ring (a regular hexagonal cap).  Every
ring count is a multiple of 6, so these meshes are exactly invariant under rotations by
60 degrees about z.
"""
from __future__ import annotations

from .composites import BUILTIN_SHAPES, dumbbell, sphere_with_two_ellipsoids, three_blobs, torus_chain
from .deformations import bend
from .icosphere import ellipsoid, hemisphere, icosphere
from .implicit import fish, mug, quadruped, table
from .planar import flat_disk, square_patch
from .revolution import capped_cylinder, ellipsoid_of_revolution, open_tube, torus
from .shape import Shape

__all__ = [
    "Shape",
    "icosphere",
    "ellipsoid",
    "ellipsoid_of_revolution",
    "torus",
    "open_tube",
    "capped_cylinder",
    "flat_disk",
    "square_patch",
    "hemisphere",
    "dumbbell",
    "three_blobs",
    "sphere_with_two_ellipsoids",
    "torus_chain",
    "table",
    "mug",
    "quadruped",
    "fish",
    "bend",
    "BUILTIN_SHAPES",
]
