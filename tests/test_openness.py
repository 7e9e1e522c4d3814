"""How open a face is to the outside (:mod:`torchakvf.parts.openness`): rays spread evenly over
the hemisphere, a convex block open everywhere, the bottom of a blind pocket hidden and an open
step's corner not, the same in any unit of length, rays cast once per face."""
from __future__ import annotations

import math

import numpy as np

from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.merge import boundary_bends
from torchakvf.parts.openness import OPEN_RAYS, FaceOpenness, hemisphere_directions
from torchakvf.shapes.implicit import _voxel_surface


def test_hemisphere_directions_are_unit_even_in_solid_angle_and_fixed():
    d = hemisphere_directions(16)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert (d[:, 2] > 0).all()
    # even in solid angle: cos θ is uniform in (0, 1), so its mean over the midpoints is 1/2
    np.testing.assert_allclose(d[:, 2].mean(), 0.5, atol=1e-12)
    np.testing.assert_array_equal(d, hemisphere_directions(16))


def _block(pocket_depth: int = 0, step: bool = False):
    """A 6 x 6 x 6 block of unit voxels: with a 2 x 2 blind pocket of ``pocket_depth`` from the
    top in its middle, or (``step``) its top front half cut away to a step 3 deep."""
    occ = np.ones((6, 6, 6), dtype=bool)
    if pocket_depth:
        occ[2:4, 2:4, 6 - pocket_depth:] = False
    if step:
        occ[:, :3, 3:] = False
    v, f, _ = _voxel_surface(occ, 1.0, (0.0, 0.0, 0.0))
    return v, f


def test_a_convex_block_is_open_everywhere():
    v, f = _block()
    np.testing.assert_array_equal(FaceOpenness(v, f).of(np.arange(len(f))), 1.0)


def test_a_blind_pocket_bottom_is_hidden_and_an_open_step_is_not():
    v, f = _block(pocket_depth=4)
    op = FaceOpenness(v, f)
    c = v[f].mean(axis=1)
    bottom = np.flatnonzero((np.abs(c[:, 2] - 2.0) < 1e-9) & (np.abs(c[:, 0] - 3) < 1) & (np.abs(c[:, 1] - 3) < 1))
    top = np.flatnonzero(np.abs(c[:, 2] - 6.0) < 1e-9)
    assert len(bottom) == 8 and len(top) == 64
    assert op.of(bottom).max() <= 0.25                    # only rays nearly straight up get out
    far = top[(np.abs(c[top, 0] - 3) > 2) | (np.abs(c[top, 1] - 3) > 2)]
    np.testing.assert_array_equal(op.of(far), 1.0)        # the outer top, away from the pocket
    # the pocket's bottom crease (concave, 90°) is mostly hidden
    dual = dual_edges(v, f)
    cav, _ = boundary_bends(dual)
    pocket = np.zeros(len(f), dtype=bool)
    pocket[bottom] = True
    at_bottom = pocket[dual.pairs[:, 0]] | pocket[dual.pairs[:, 1]]
    crease = at_bottom & (dual.dihedral > 1.0)
    assert crease.sum() == 8
    hidden = op.hidden_bends(dual, cav, np.ones(len(cav), dtype=bool))
    assert (hidden[crease] >= 0.5 * cav[crease]).all() and (hidden[crease] < cav[crease] + 1e-12).all()
    assert (hidden[dual.dihedral <= math.radians(10)] == 0).all()
    # a step's concave corner in the open: each face sees about half its sky, not hidden
    v2, f2 = _block(step=True)
    dual2 = dual_edges(v2, f2)
    cav2, _ = boundary_bends(dual2)
    corner = dual2.dihedral > 1.0
    assert corner.sum() == 6
    hidden2 = FaceOpenness(v2, f2).hidden_bends(dual2, cav2, np.ones(len(cav2), dtype=bool))
    assert (hidden2[corner] <= 0.25 * cav2[corner]).all()
    # only the selected edges are cast from and carry weight
    none = FaceOpenness(v, f)
    np.testing.assert_array_equal(none.hidden_bends(dual, cav, np.zeros(len(cav), dtype=bool)), 0.0)
    assert np.isnan(none.known).all()


def test_openness_is_the_same_in_any_unit_and_cast_once_per_face():
    v, f = _block(pocket_depth=3)
    ids = np.arange(0, len(f), 3)
    op = FaceOpenness(v, f)
    a = op.of(ids)
    assert set(np.unique(a * OPEN_RAYS)) <= set(range(OPEN_RAYS + 1))    # a share of the rays
    assert 0 < (a < 1).sum() < len(ids)
    np.testing.assert_array_equal(FaceOpenness(v * 2.0 ** -12, f).of(ids), a)
    np.testing.assert_array_equal(FaceOpenness(v * 2.0 ** 20 + 5.0, f).of(ids), a)
    known = op.known.copy()
    assert np.isfinite(known[ids]).all() and np.isnan(np.delete(known, ids)).all()
    op.known[ids] = -1.0                       # a second ask reads what was cast, not cast again
    np.testing.assert_array_equal(op.of(ids[:5]), -1.0)
