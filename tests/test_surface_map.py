"""Closest points on a triangle mesh (torchakvf.mesh.surface_map): both searches of
SurfaceIndex exact against brute force (ties, slivers, points off the surface), and the
fallback without libigl."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.mesh.surface_map import SurfaceIndex, closest_barycentric, libigl_available, locate_on_surface

#: The closest-point searches of SurfaceIndex; "aabb" needs libigl.
SEARCHES = ["samples", pytest.param("aabb", marks=pytest.mark.skipif(not libigl_available(),
                                                                    reason="libigl is not installed"))]


def _brute_force_closest(vertices, faces, points):
    """Closest point over every face, by dense sampling-free projection (independent check:
    a fine barycentric grid on each triangle)."""
    g = np.linspace(0, 1, 61)
    u, v = np.meshgrid(g, g)
    keep = (u + v) <= 1
    bary = np.stack([1 - u[keep] - v[keep], u[keep], v[keep]], axis=1)      # [S, 3]
    tri = vertices[faces]                                                     # [F, 3, 3]
    samples = np.einsum("sc,fcx->fsx", bary, tri).reshape(-1, 3)
    return np.concatenate([np.linalg.norm(samples[None] - points[i:i + 20, None], axis=-1).min(axis=1)
                           for i in range(0, len(points), 20)])          # ([20, S, 3] at a time)


def test_located_points_reconstruct_and_match_brute_force():
    s = shapes.icosphere(2)
    rng = np.random.default_rng(0)
    f = rng.integers(len(s.faces), size=200)
    w = rng.dirichlet(np.ones(3), size=200)
    on = np.einsum("pc,pcx->px", w, s.vertices[s.faces[f]])
    normal = on / np.linalg.norm(on, axis=1, keepdims=True)
    points = on + normal * rng.uniform(-0.02, 0.02, size=(200, 1))
    loc = locate_on_surface(s.vertices, s.faces, points)
    assert np.all(loc.bary >= -1e-12) and np.allclose(loc.bary.sum(1), 1)
    closest = np.einsum("pc,pcx->px", loc.bary, s.vertices[s.faces[loc.face]])
    assert np.allclose(np.linalg.norm(closest - points, axis=1), loc.distance)
    # Each point's distance to the mesh is no more than the brute-force one (up to its grid).
    brute = _brute_force_closest(s.vertices, s.faces, points)
    assert np.all(loc.distance <= brute + 1e-9)
    assert np.all(brute - loc.distance < 0.02)
    # Linear interpolation of a linear function of the vertices is exact on the surface.
    values = s.vertices @ np.array([1.0, -2.0, 0.5])
    assert np.allclose(loc.interpolate(s.faces, values), closest @ np.array([1.0, -2.0, 0.5]))


def test_point_outside_a_triangle_snaps_to_its_edge_and_corner():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    loc = locate_on_surface(v, f, np.array([[0.5, -1.0, 0.3], [2.0, -1.0, 0.0], [0.25, 0.25, 1.0]]))
    assert np.allclose(loc.bary[0], [0.5, 0.5, 0.0])          # nearest point on edge (0, 1)
    assert np.allclose(loc.bary[1], [0.0, 1.0, 0.0])          # corner 1
    assert np.allclose(loc.bary[2], [0.5, 0.25, 0.25])        # above the interior
    assert np.allclose(loc.distance, [np.hypot(1.0, 0.3), np.hypot(1.0, 1.0), 1.0])


def _every_face_closest(vertices, faces, points):
    """Brute force: Ericson's closest point on every face for every point; [P] face (lowest
    index among the nearest) and distance."""
    tri = vertices[faces]
    a, b, c = tri[None, :, 0], tri[None, :, 1], tri[None, :, 2]
    w = closest_barycentric(points[:, None, :], a, b, c)                  # [P, F, 3]
    q = w[..., 0:1] * a + w[..., 1:2] * b + w[..., 2:3] * c
    d = np.linalg.norm(q - points[:, None, :], axis=-1)
    return d.argmin(axis=1), d.min(axis=1), d


def _check_exact(vertices, faces, points, search="auto"):
    loc = locate_on_surface(vertices, faces, points, index=SurfaceIndex(vertices, faces, search=search))
    scale = np.abs(vertices).max()
    face, dist, found, second = [], [], [], []
    for i in range(0, len(points), 200):      # brute force in chunks ([P, F, 3] arrays)
        f, d, all_d = _every_face_closest(vertices, faces, points[i:i + 200])
        face.append(f), dist.append(d)
        found.append(all_d[np.arange(len(f)), loc.face[i:i + 200]])
        second.append(np.sort(all_d, axis=1)[:, 1] if all_d.shape[1] > 1 else np.full(len(f), np.inf))
    face, dist, found, second = map(np.concatenate, (face, dist, found, second))
    # Same distance as brute force, and the face found is one of the nearest (a different
    # face only where two faces are equally near within round-off: a shared edge or corner).
    assert np.allclose(loc.distance, dist, rtol=0, atol=1e-12 * scale)
    assert np.all(found <= dist + 1e-12 * scale)
    tie = second - dist <= 1e-12 * scale
    assert np.array_equal(loc.face[~tie], face[~tie])
    assert np.all(loc.bary >= -1e-12) and np.allclose(loc.bary.sum(1), 1)
    closest = np.einsum("pc,pcx->px", loc.bary, vertices[faces[loc.face]])
    assert np.allclose(np.linalg.norm(closest - points, axis=1), loc.distance, atol=1e-12 * scale)
    return tie


def _points_with_ties(s, seed):
    """[1200, 3] points around shape s: anywhere, near the surface, on edges, near corners."""
    rng = np.random.default_rng(seed)
    lo, hi = s.vertices.min(0), s.vertices.max(0)
    far = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), size=(300, 3))   # anywhere
    f = rng.integers(len(s.faces), size=300)
    on = np.einsum("pc,pcx->px", rng.dirichlet(np.ones(3), size=300), s.vertices[s.faces[f]])
    near = on + rng.normal(scale=0.01 * (hi - lo).max(), size=on.shape)       # near the surface
    # Points on edges and corners, and pushed off them: where several faces are equally near.
    e = s.faces[f]
    t = rng.uniform(size=(300, 1))
    edge = t * s.vertices[e[:, 0]] + (1 - t) * s.vertices[e[:, 1]]
    corner = s.vertices[e[:, 2]] * (1 + rng.uniform(-0.05, 0.05, size=(300, 1)))
    return np.concatenate([far, near, edge, corner])


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize("shape", ["torus", "dumbbell", "icosphere"])
def test_locate_is_exact_against_every_face_on_builtin_meshes(shape, search):
    s = shapes.icosphere(2) if shape == "icosphere" else getattr(shapes, shape)()
    tie = _check_exact(s.vertices, s.faces, _points_with_ties(s, 1), search)
    assert tie.sum() > 50                                      # the ties were exercised


@pytest.mark.skipif(not libigl_available(), reason="libigl is not installed")
@pytest.mark.parametrize("shape", ["torus", "dumbbell", "icosphere"])
def test_aabb_and_sample_searches_agree(shape):
    # The same bits wherever one face is nearest by more than round-off, and wherever the
    # nearest faces meet at the closest point (an edge or corner: the AABB search measures the
    # faces around it and settles their tie as the sample search does). Only two faces
    # equally near at two different points (a symmetric configuration) may go either way.
    s = shapes.icosphere(2) if shape == "icosphere" else getattr(shapes, shape)()
    rng = np.random.default_rng(5)
    vert = rng.choice(len(s.vertices), size=min(300, len(s.vertices)), replace=False)
    face = rng.choice(len(s.faces), size=300)
    points = np.concatenate([_points_with_ties(s, 4), s.vertices[vert],
                             0.5 * (s.vertices[s.faces[face, 0]] + s.vertices[s.faces[face, 1]])])
    a = SurfaceIndex(s.vertices, s.faces, search="samples").locate(points)
    b = SurfaceIndex(s.vertices, s.faces, search="aabb").locate(points)
    scale = np.abs(s.vertices).max()
    assert np.allclose(a.distance, b.distance, rtol=0, atol=1e-12 * scale)
    # How many faces are nearest within round-off, by brute force (in chunks: [P, F, 3] arrays).
    count = np.concatenate([(lambda d: (d[2] <= d[1][:, None] + 1e-9 * scale).sum(axis=1))(
        _every_face_closest(s.vertices, s.faces, points[i:i + 200])) for i in range(0, len(points), 200)])
    one = count == 1
    same = (a.face == b.face) & (a.bary == b.bary).all(axis=1) & (a.distance == b.distance)
    assert same[one].all()
    # Points on vertices and edge midpoints (every face around them equally near, up to
    # round-off): the AABB search's pick is resolved over them as the sample search's is.
    v = len(_points_with_ties(s, 4))
    assert (~one[v:]).all() and same[v:].all()


@pytest.mark.parametrize("search", SEARCHES)
def test_locate_takes_no_points_and_refuses_non_finite_ones(search):
    s = shapes.icosphere(1)
    index = SurfaceIndex(s.vertices, s.faces, search=search)
    none = index.locate(np.zeros((0, 3)))
    assert none.face.shape == (0,) and none.bary.shape == (0, 3) and none.distance.shape == (0,)
    with pytest.raises(ParameterError, match="1 of 2 points .* not finite .* row 0"):
        index.locate(np.array([[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    with pytest.raises(ParameterError, match="not finite"):
        index.locate(np.array([[0.0, np.inf, 0.0]]))


def test_surface_index_search_is_checked(monkeypatch):
    s = shapes.icosphere(1)
    with pytest.raises(ParameterError, match="search"):
        SurfaceIndex(s.vertices, s.faces, search="bvh")
    monkeypatch.setitem(sys.modules, "igl", None)                     # libigl not importable
    with pytest.raises(ParameterError, match="libigl"):
        SurfaceIndex(s.vertices, s.faces, search="aabb")
    assert SurfaceIndex(s.vertices, s.faces).search == "samples"      # the fallback without it


@pytest.mark.parametrize("search", SEARCHES)
def test_locate_is_exact_on_a_random_soup_with_slivers(search):
    # Random triangles of very different sizes and shapes (slivers included), and points among
    # them: where the nearest barycenters say little about the nearest face.
    rng = np.random.default_rng(2)
    centers = rng.uniform(-1, 1, size=(400, 3))
    size = np.exp(rng.uniform(np.log(0.01), np.log(0.5), size=(400, 1, 1)))
    tri = centers[:, None] + size * rng.normal(size=(400, 3, 3))
    tri[:40, 2] = tri[:40, 0] + 1e-3 * (tri[:40, 1] - tri[:40, 0]) + 1e-4   # slivers
    v = tri.reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    _check_exact(v, f, rng.uniform(-1.2, 1.2, size=(500, 3)), search)


@pytest.mark.parametrize("search", SEARCHES)
def test_locate_finds_what_nearest_barycenters_miss(search):
    # A long triangle whose barycenter is far away, next to many small ones: the point lies
    # over the long one's far end (the 8 faces with the nearest barycenters hold only small
    # ones, the nearest of them 29 units away).
    small = np.array([[[x, 1.0, 0.0], [x + 0.1, 1.0, 0.0], [x, 1.1, 0.0]] for x in np.linspace(-0.5, 0.5, 20)])
    long = np.array([[[-50.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, -1.0, 0.0]]])
    tri = np.concatenate([small, long])
    v = tri.reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    loc = SurfaceIndex(v, f, search=search).locate(np.array([[30.0, 0.05, 0.0]]))
    assert loc.face[0] == 20 and np.isclose(loc.distance[0], 0.05)


@pytest.mark.parametrize("search", SEARCHES)
@pytest.mark.parametrize("left_first", [True, False])
def test_a_point_above_a_ridge_goes_to_the_face_it_lies_squarely_above(search, left_first):
    # A tent: ridge along x at z = 1, the left slope down to y = -1, the right to y = +1. A point
    # above the ridge, a little to the left, is exactly as near both slopes (its closest point is
    # the ridge on each); the left slope's normal (0, -1, 1)/√2 is nearer its offset (0, -0.1,
    # 0.5): |cos| 0.6/√2/|offset| against 0.4/√2/|offset|. Whatever the numbering and pose.
    v = np.array([[0.0, 0, 1], [1, 0, 1], [0.5, -1, 0], [0.5, 1, 0]])
    left, right = [0, 1, 2], [0, 1, 3]
    faces = np.array([left, right] if left_first else [right, left])
    p = np.array([[0.5, -0.1, 1.5]])
    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    for rot, shift in ((np.eye(3), np.zeros(3)), (q, np.array([3.0, -1.0, 2.0]))):
        got = SurfaceIndex(v @ rot.T + shift, faces, search=search).locate(p @ rot.T + shift)
        assert got.face[0] == (0 if left_first else 1)
        np.testing.assert_allclose(got.distance[0], np.hypot(0.1, 0.5), rtol=1e-12)
        np.testing.assert_allclose(got.interpolate(faces, v)[0], [0.5, 0, 1], atol=1e-12)


@pytest.mark.parametrize("search", SEARCHES)
def test_a_moved_renumbered_mesh_locates_every_point_on_the_same_face(search):
    # Points just off a decimated sphere lie above its edges and corners as often as not; ties
    # there were settled by round-off, which a rigid motion changes.
    from torchakvf import Mesh
    from torchakvf.mesh.coarse import decimate

    sphere = shapes.icosphere(4)
    coarse = decimate(Mesh(sphere.vertices, sphere.faces), 300)
    v, f = np.asarray(coarse.vertices, float), np.asarray(coarse.faces)
    rng = np.random.default_rng(0)
    points = np.asarray(sphere.vertices, float) * 1.01
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    shift = np.array([1.0, -2.0, 0.5])
    pf = rng.permutation(len(f))
    base = SurfaceIndex(v, f, search=search).locate(points)
    moved = SurfaceIndex(v @ q.T + shift, f[pf], search=search).locate(points @ q.T + shift)
    assert (np.argsort(pf)[base.face] == moved.face).all()
    np.testing.assert_allclose(moved.distance, base.distance, rtol=1e-9, atol=1e-12)
