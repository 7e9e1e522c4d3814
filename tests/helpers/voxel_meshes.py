"""Voxel test meshes: a U (a base and two arms) whose parts are boxes, for the lines of sight
and the merge that reads them."""
from __future__ import annotations

import numpy as np

from torchakvf.shapes.implicit import _voxel_surface


def voxel_u():
    """A U of voxels (unit 0.1): a base 8 x 2 x 2 and two arms 2 x 2 x 6 on its ends, a gap of
    4 voxels between them. Returns (vertices [V, 3], faces [F, 3] outward, x [F], z [F]): the
    x and z index of the voxel behind each face (the base is z < 2, the left arm x < 4)."""
    occ = np.zeros((8, 2, 8), dtype=bool)
    occ[:, :, :2] = True
    occ[:2, :, 2:] = True
    occ[6:, :, 2:] = True
    v, f, owner = _voxel_surface(occ, 0.1, (0.0, 0.0, 0.0))
    x, _, z = np.unravel_index(owner, occ.shape)
    return v, f, x, z


def voxel_step_with_pocket():
    """A block of unit voxels 6 x 8 x 6 with a step (its front, y < 3, cut down to z = 3) and a
    blind pocket 2 x 2 from the top of its back down to z = 2. Returns (vertices [V, 3], faces
    [F, 3] outward, labels [F]): 0 the front (faces with centroid y < 3, the step's tread among
    them), 2 the pocket's floor, 1 the rest (the riser, the pocket's walls): the step's concave
    corner lies in the open between 0 and 1, the pocket's floor crease hidden between 1 and 2."""
    occ = np.ones((6, 8, 6), dtype=bool)
    occ[:, :3, 3:] = False
    occ[2:4, 5:7, 2:] = False
    v, f, _ = _voxel_surface(occ, 1.0, (0.0, 0.0, 0.0))
    c = v[f].mean(axis=1)
    floor = (np.abs(c[:, 2] - 2.0) < 1e-9) & (c[:, 0] > 2) & (c[:, 0] < 4) & (c[:, 1] > 5) & (c[:, 1] < 7)
    return v, f, np.where(floor, 2, np.where(c[:, 1] < 3, 0, 1))
