"""Signed distances of the solid primitives (torchakvf.shapes.sdf) against distances computed
by hand, against each other where two describe one solid, and against a brute-force distance
to a polygon's densely sampled boundary; frames, bounds and the combining operations."""
from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath

from torchakvf.shapes import sdf


def _pts(*rows) -> np.ndarray:
    return np.array(rows, dtype=np.float64)


def test_box_and_rounded_box_by_hand():
    box = sdf.Box(half=(1.0, 2.0, 3.0))
    np.testing.assert_allclose(box(_pts([2, 0, 0], [2, 3, 0], [2, 3, 5], [0, 0, 0], [0.5, 1.5, 0])),
                               [1.0, np.sqrt(2), np.sqrt(6), -1.0, -0.5], atol=1e-15)
    rounded = sdf.Box(half=(1.0, 1.0, 1.0), rounding=0.25)
    # Beyond a corner: distance to the corner sphere of radius 0.25 centred at (0.75, 0.75, 0.75).
    np.testing.assert_allclose(rounded(_pts([2, 2, 2], [2, 0, 0])), [np.sqrt(3) * 1.25 - 0.25, 1.0], atol=1e-15)


def test_cylinder_cone_and_round_cone_by_hand():
    cyl = sdf.cylinder((0, 0, 0), (0, 0, 2), 1.0)
    np.testing.assert_allclose(cyl(_pts([3, 0, 1], [0, 0, 3], [2, 0, 3], [0.5, 0, 1], [0, 0, 0.2])),
                               [2.0, 1.0, np.sqrt(2), -0.5, -0.2], atol=1e-12)
    cone = sdf.Frustum((0, 0, 0), (0, 0, 1), 1.0, 0.0)          # the slant is the line r + z = 1
    np.testing.assert_allclose(cone(_pts([0, 0, 2], [1, 0, 1], [0, 0, -0.5], [0.2, 0, 0.2])),
                               [1.0, 1 / np.sqrt(2), 0.5, -0.2], atol=1e-12)
    rc = sdf.RoundCone((0, 0, 0), (0, 0, 3), 1.0, 0.5)
    # On the axis at z = 1: 1 - z sin(a) from the slant, sin(a) = (1 - 0.5) / 3.
    np.testing.assert_allclose(rc(_pts([0, 0, -2], [0, 0, 5], [0, 0, 1])), [1.0, 1.5, -5 / 6], atol=1e-12)


def test_capsule_forms_agree():
    rng = np.random.default_rng(0)
    x = rng.uniform(-2, 3, size=(500, 3))
    a, b = (0.1, -0.3, 0.2), (1.2, 0.8, 1.9)
    np.testing.assert_allclose(sdf.capsule(a, b, 0.4)(x), sdf.capsule_sdf(x, a, b, 0.4), atol=1e-12)


def test_torus_and_arcs_by_hand():
    ring = sdf.Torus(major=2.0, minor=0.5)
    np.testing.assert_allclose(ring(_pts([0, 0, 0], [2, 0, 1], [0, 3, 0], [2, 0, 0])), [1.5, 0.5, 0.5, -0.5])
    quarter = dict(major=2.0, minor=0.5, arc=np.pi / 2)
    p = _pts([2, -1, 0], [0, 3, 0], [-2, 0, 0])
    # Beyond the ends: the rounded arc measures to the end points, the flat one to the end discs.
    np.testing.assert_allclose(sdf.Torus(**quarter)(p), [0.5, 0.5, np.hypot(2, 2) - 0.5], atol=1e-12)
    # (0, 3, 0) lies in the end disc's plane, 0.5 from its rim; (-2, 0, 0) is nearest the rim
    # point (0, 1.5, 0) of the far end's disc.
    np.testing.assert_allclose(sdf.Torus(**quarter, flat_ends=True)(p), [1.0, 0.5, 2.5], atol=1e-12)
    # Inside a flat arc near its end, the end face is nearest.
    np.testing.assert_allclose(sdf.Torus(**quarter, flat_ends=True)(_pts([2, 0.1, 0])), [-0.1], atol=1e-12)


def test_solids_described_two_ways_agree():
    rng = np.random.default_rng(1)
    x = rng.uniform(-2, 2, size=(2000, 3))
    square = sdf.Extrusion(polygon=((1, 1), (-1, 1), (-1, -1), (1, -1)), half_height=1.0)
    np.testing.assert_allclose(square(x), sdf.Box(half=(1, 1, 1))(x), atol=1e-12)
    turned = sdf.Revolved(profile=((0, -1), (1, -1), (1, 1), (0, 1)))
    np.testing.assert_allclose(turned(x), sdf.cylinder((0, 0, -1), (0, 0, 1), 1.0)(x), atol=1e-12)
    sphere = sdf.Ellipsoid(center=(0.2, 0, 0), axes=(0.8, 0.8, 0.8))
    np.testing.assert_allclose(sphere(x), np.linalg.norm(x - [0.2, 0, 0], axis=1) - 0.8, atol=1e-12)


def test_ellipsoid_exact_on_surface_and_axes():
    e = sdf.Ellipsoid(axes=(2.0, 1.0, 0.1))
    t = np.linspace(0, 2 * np.pi, 50)
    on = np.stack([2 * np.cos(t), np.sin(t), np.zeros_like(t)], axis=1)
    np.testing.assert_allclose(e(on), 0.0, atol=1e-12)
    np.testing.assert_allclose(e(_pts([3, 0, 0], [0, 0, 0.6], [0, 1.5, 0])), [1.0, 0.5, 0.5], atol=1e-12)
    # Beside a thin ellipsoid (a fin) the distance stays close to the true one (0.5 here),
    # where one scaled by the smallest semi-axis would say 0.025.
    assert e(_pts([2.5, 0, 0]))[0] == pytest.approx(0.5)
    assert sdf.ellipsoid_sdf(_pts([2.5, 0, 0]), (0, 0, 0), (2.0, 1.0, 0.1))[0] == pytest.approx(0.025)


def test_polygon_distance_against_a_sampled_boundary():
    poly = np.array([(0, 0), (3, 0), (3, 2), (1.5, 0.8), (0, 2)])         # not convex
    rng = np.random.default_rng(2)
    p = rng.uniform(-1, 4, size=(400, 2))
    d = sdf.polygon_sdf(p, poly)
    t = np.linspace(0, 1, 4001)[:, None]
    boundary = np.concatenate([poly[i - 1] + t * (poly[i] - poly[i - 1]) for i in range(len(poly))])
    brute = np.min(np.linalg.norm(p[:, None] - boundary[None], axis=2), axis=1)
    np.testing.assert_allclose(np.abs(d), brute, atol=1e-3)
    inside = PolygonPath(poly).contains_points(p)
    assert np.array_equal(d < 0, inside)
    assert np.allclose(sdf.polygon_sdf(p, poly[::-1]), d)               # either winding


def test_frames_move_solids_rigidly():
    rng = np.random.default_rng(3)
    rot = sdf.random_rotation(rng)
    assert np.allclose(rot @ rot.T, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1.0)
    assert np.allclose(sdf.rotation((0, 0, 1), np.pi / 2) @ [1, 0, 0], [0, 1, 0])
    f = sdf.frame((1, 1, 0), x_hint=(0, 0, 1))
    assert np.allclose(f[:, 2], np.array([1, 1, 0]) / np.sqrt(2)) and np.allclose(f[:, 0], [0, 0, 1])
    x = rng.uniform(-2, 2, size=(300, 3))
    centre = np.array([0.3, -0.2, 0.5])
    moved = sdf.Box(center=tuple(centre), rotation=rot, half=(1.0, 0.5, 0.25), rounding=0.1)
    np.testing.assert_allclose(moved(x @ rot.T + centre), sdf.Box(half=(1.0, 0.5, 0.25), rounding=0.1)(x), atol=1e-12)


@pytest.mark.parametrize("solid", [
    sdf.Box(center=(1, 0, 0), rotation=sdf.rotation((1, 2, 3), 0.7), half=(1.0, 0.3, 0.2)),
    sdf.Ellipsoid(center=(0, 1, 0), rotation=sdf.rotation((0, 1, 1), 1.1), axes=(1.2, 0.4, 0.1)),
    sdf.RoundCone((0, 0, 0), (1, 1, 0), 0.3, 0.1),
    sdf.Frustum((0, 0, 0), (0, 1, 1), 0.5, 0.2),
    sdf.Torus(center=(0, 0, 1), rotation=sdf.rotation((1, 0, 0), 0.5), major=1.0, minor=0.2),
    sdf.Extrusion(rotation=sdf.rotation((0, 1, 0), 0.4), polygon=((0, 0), (1, 0), (0, 1)), half_height=0.1),
    sdf.Revolved(center=(0, 0, -1), rotation=sdf.rotation((1, 1, 0), 0.9),
                 profile=((0, 0), (0.5, 0), (0.2, 1), (0, 1))),
])
def test_bounds_hold_the_solid(solid):
    lo, hi = solid.bounds()
    rng = np.random.default_rng(4)
    x = rng.uniform(lo - 0.2, hi + 0.2, size=(50000, 3))
    inside = solid(x) < 0
    assert inside.sum() > 100
    assert np.all((x[inside] >= lo - 1e-12) & (x[inside] <= hi + 1e-12))


def test_union_and_difference():
    a, b = sdf.Box(half=(1, 1, 1)), sdf.Ellipsoid(center=(1, 0, 0), axes=(0.5, 0.5, 0.5))
    x = np.random.default_rng(5).uniform(-2, 2, size=(1000, 3))
    np.testing.assert_array_equal(sdf.Union((a, b))(x), np.minimum(a(x), b(x)))
    smooth = sdf.Union((a, b), blend=0.3)(x)
    assert np.all(smooth <= np.minimum(a(x), b(x))) and np.all(smooth >= np.minimum(a(x), b(x)) - 0.3 / 4)
    np.testing.assert_array_equal(sdf.Difference(a, b)(x), np.maximum(a(x), -b(x)))
    lo, hi = sdf.union_bounds([a, b])
    assert np.allclose(lo, [-1, -1, -1]) and np.allclose(hi, [1.5, 1, 1])
