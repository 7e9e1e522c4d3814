"""Meshing a signed distance function (torchakvf.shapes.marching): marching cubes and
marching tetrahedra give closed, manifold, outward surfaces near the zero set; the clamp keeps
every triangle away from degenerate; relaxation keeps vertices on the surface and folds
nothing."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf.shapes import sdf
from torchakvf.shapes.marching import marching_cubes, marching_tetrahedra, relax


def _sphere(x):
    return np.linalg.norm(x - [0.05, -0.02, 0.03], axis=1) - 1.0


def _topology(v, f):
    """(every edge on two faces, every directed edge once, signed volume, Euler characteristic)."""
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    tri = v[f]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    return (bool(np.all(count == 2)), len(np.unique(directed, axis=0)) == len(directed), volume,
            len(v) - len(count) + len(f))


def _quality(v, f):
    """Per face 4 sqrt(3) area / (sum of squared edges): 1 equilateral, 0 degenerate."""
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return 4 * np.sqrt(3) * area / np.sum((tri - np.roll(tri, 1, axis=1)) ** 2, axis=(1, 2))


@pytest.mark.parametrize("mesher", ["cubes", "tetrahedra"])
def test_sphere_is_closed_outward_and_near(mesher):
    h = 0.1
    if mesher == "cubes":
        v, f = marching_cubes(_sphere, (-1.3,) * 3, (1.3,) * 3, h, clamp=0.1)
    else:
        v, f = marching_tetrahedra(_sphere, (-1.3,) * 3, (1.3,) * 3, h, clamp=0.1, orient=True)
    closed, oriented, volume, euler = _topology(v, f)
    assert closed and oriented and euler == 2
    assert volume == pytest.approx(4 / 3 * np.pi, rel=0.03)          # positive: outward
    # Linear crossings lie within a grid step of the sphere (a chord's sagitta is far less).
    assert np.abs(_sphere(v)).max() < 0.1 * h + 0.01
    assert _quality(v, f).min() > 0.05                                 # the clamp: no needles
    assert f.dtype == np.int64 and v.dtype == np.float64


def test_cubes_make_a_third_of_the_faces_of_tetrahedra():
    box = sdf.Box(rotation=sdf.rotation((1, 2, 3), 0.4), half=(0.8, 0.5, 0.3))
    fc = marching_cubes(box, (-1.1,) * 3, (1.1,) * 3, 0.05)[1]
    ft = marching_tetrahedra(box, (-1.1,) * 3, (1.1,) * 3, 0.05)[1]
    area = 8 * (0.8 * 0.5 + 0.8 * 0.3 + 0.5 * 0.3)
    assert 2.5 < len(fc) * 0.05 ** 2 / area < 3.5 < len(ft) * 0.05 ** 2 / area


def test_thin_slab_keeps_both_sides():
    """A disc two grid steps thick, at a slant: one closed surface with both faces."""
    axis = np.array([1.0, 2.0, 2.0]) / 3
    disc = sdf.cylinder(-0.1 * axis, 0.1 * axis, 1.0)
    v, f = marching_cubes(disc, (-1.2,) * 3, (1.2,) * 3, 0.1, clamp=0.1)
    closed, oriented, volume, euler = _topology(v, f)
    assert closed and oriented and euler == 2 and volume > 0
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    up = n @ axis / np.linalg.norm(n, axis=1)
    area = 0.5 * np.linalg.norm(n, axis=1)
    for side in (up > 0.9, up < -0.9):                   # each flat side about pi in area
        assert area[side].sum() == pytest.approx(np.pi, rel=0.15)


def test_relax_keeps_the_surface_and_improves_triangles():
    ell = sdf.Ellipsoid(rotation=sdf.rotation((0, 1, 1), 0.3), axes=(1.0, 0.6, 0.3))
    v, f = marching_cubes(ell, (-1.2,) * 3, (1.2,) * 3, 0.08, clamp=0.1)
    r = relax(ell, v, f, iterations=20)
    assert np.abs(ell(r)).max() < 1e-6                     # on the surface (one Newton step a step)
    assert np.median(_quality(r, f)) > np.median(_quality(v, f)) + 0.05
    assert _quality(r, f).min() >= min(0.05, 0.5 * _quality(v, f).min())
    closed, oriented, volume, _ = _topology(r, f)
    assert closed and oriented and volume == pytest.approx(4 / 3 * np.pi * 0.18, rel=0.02)
    # No face turned against the surface's normal.
    tri = r[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(1)
    g = np.stack([(ell(c + 1e-6 * e) - ell(c - 1e-6 * e)) / 2e-6 for e in np.eye(3)], axis=1)
    assert np.all(np.einsum("ij,ij->i", n, g) > 0)
