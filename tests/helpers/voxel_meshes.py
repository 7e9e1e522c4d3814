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
