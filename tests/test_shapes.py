"""Tests for torchakvf.shapes: topology, orientation, triangle quality, parts and bend."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from torchakvf import shapes
from torchakvf.shapes import BUILTIN_SHAPES, Shape, bend


def _edges(faces):
    """Undirected edges (sorted pairs), one row per face side."""
    return np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)


def _unique_edges(faces):
    return np.unique(_edges(faces), axis=0)


def _face_angles_deg(vertices, faces):
    """Interior angles, shape (F, 3), in degrees."""
    tri = vertices[faces]
    out = []
    for i in range(3):
        u = tri[:, (i + 1) % 3] - tri[:, i]
        w = tri[:, (i + 2) % 3] - tri[:, i]
        cos = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def _signed_volume(vertices, faces):
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def _n_components(shape):
    e = _unique_edges(shape.faces)
    n = len(shape.vertices)
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[0]


def check_mesh(shape: Shape, closed: bool, euler: int):
    """Everything the module promises for every mesh."""
    v, f = shape.vertices, shape.faces
    assert isinstance(shape.name, str) and shape.name
    assert v.dtype == np.float64 and v.ndim == 2 and v.shape[1] == 3
    assert f.dtype == np.int64 and f.ndim == 2 and f.shape[1] == 3
    assert np.isfinite(v).all()
    # every vertex used, no duplicate vertices
    assert np.array_equal(np.unique(f), np.arange(len(v)))
    assert len(np.unique(np.round(v, 9), axis=0)) == len(v)
    # no degenerate faces (area relative to the squared mean edge length)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    lengths = np.linalg.norm(v[_edges(f)[:, 0]] - v[_edges(f)[:, 1]], axis=1)
    assert area.min() > 1e-3 * lengths.mean() ** 2
    # edge manifold, and consistently oriented: no directed edge used twice
    _, per_edge = np.unique(_edges(f), axis=0, return_counts=True)
    if closed:
        assert np.all(per_edge == 2)
    else:
        assert np.all((per_edge == 1) | (per_edge == 2)) and np.any(per_edge == 1)
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len(np.unique(directed, axis=0)) == len(directed)
    # vertex manifold on the boundary: boundary loops never touch
    boundary = np.unique(_edges(f), axis=0)[per_edge == 1]
    if len(boundary):
        assert np.all(np.bincount(boundary.ravel())[np.unique(boundary)] == 2)
    n_edges = len(per_edge)
    assert len(v) - n_edges + len(f) == euler
    if closed:
        assert _signed_volume(v, f) > 0
    if shape.part_labels is None:
        assert shape.n_parts == 1
    else:
        assert shape.part_labels.dtype == np.int64
        assert shape.part_labels.shape == (len(f),)
        assert np.array_equal(np.unique(shape.part_labels), np.arange(shape.n_parts))


@pytest.mark.parametrize("level,n_faces,n_edges", [(3, 1280, 1920), (4, 5120, 7680)])
def test_icosphere_counts(level, n_faces, n_edges):
    s = shapes.icosphere(level)
    check_mesh(s, closed=True, euler=2)
    assert len(s.faces) == n_faces
    assert len(_unique_edges(s.faces)) == n_edges
    assert len(s.vertices) == n_edges - n_faces + 2
    assert np.allclose(np.linalg.norm(s.vertices, axis=1), 1.0)


def test_icosphere_radius():
    s = shapes.icosphere(2, radius=2.5)
    assert np.allclose(np.linalg.norm(s.vertices, axis=1), 2.5)


def test_ellipsoid():
    s = shapes.ellipsoid()
    check_mesh(s, closed=True, euler=2)
    assert len(s.faces) == 5120
    x, y, z = s.vertices.T
    assert np.allclose((x / 1.0) ** 2 + (y / 1.3) ** 2 + (z / 1.7) ** 2, 1.0)


def test_ellipsoid_of_revolution():
    s = shapes.ellipsoid_of_revolution(a=1.0, c=1.6)
    check_mesh(s, closed=True, euler=2)
    x, y, z = s.vertices.T
    assert np.allclose(x ** 2 + y ** 2 + (z / 1.6) ** 2, 1.0, atol=1e-6)
    assert np.isclose(z.min(), -1.6) and np.isclose(z.max(), 1.6)


@pytest.mark.parametrize("make", [shapes.ellipsoid_of_revolution, shapes.torus, shapes.dumbbell])
def test_revolved_meshes_have_sixfold_symmetry(make):
    s = make()
    c, si = np.cos(np.pi / 3), np.sin(np.pi / 3)
    rotated = s.vertices @ np.array([[c, -si, 0.0], [si, c, 0.0], [0.0, 0.0, 1.0]]).T
    key = {tuple(p): i for i, p in enumerate(np.round(s.vertices, 9))}
    image = np.array([key[tuple(p)] for p in np.round(rotated, 9)])
    assert set(map(tuple, np.sort(image[s.faces], axis=1))) == set(map(tuple, np.sort(s.faces, axis=1)))


def test_torus():
    s = shapes.torus(major=1.0, minor=0.4)
    check_mesh(s, closed=True, euler=0)
    x, y, z = s.vertices.T
    assert np.allclose((np.hypot(x, y) - 1.0) ** 2 + z ** 2, 0.16)
    assert np.isclose(_signed_volume(s.vertices, s.faces), 2 * np.pi ** 2 * 0.4 ** 2, rtol=0.02)
    with pytest.raises(ValueError):
        shapes.torus(major=0.3, minor=0.4)


def test_torus_explicit_minor_count():
    s = shapes.torus(n_major=36, n_minor=12)
    check_mesh(s, closed=True, euler=0)
    assert len(np.unique(np.round(np.arctan2(s.vertices[:, 2], np.hypot(*s.vertices[:, :2].T) - 1), 9))) == 12


def test_open_tube():
    s = shapes.open_tube(radius=1.0, length=3.0, n_around=48)
    check_mesh(s, closed=False, euler=0)
    assert np.allclose(np.hypot(*s.vertices[:, :2].T), 1.0)
    z = s.vertices[:, 2]
    assert np.isclose(z.min(), -1.5) and np.isclose(z.max(), 1.5)
    per_edge = np.unique(_edges(s.faces), axis=0, return_counts=True)[1]
    assert np.sum(per_edge == 1) == 2 * 48                  # two boundary loops of 48
    assert len(shapes.open_tube(n_around=48, n_rings=5).faces) == 2 * 48 * 4


def test_capped_cylinder():
    s = shapes.capped_cylinder(radius=1.0, height=3.0)
    check_mesh(s, closed=True, euler=2)
    x, y, z = s.vertices.T
    on_side = np.isclose(np.hypot(x, y), 1.0)
    on_cap = np.isclose(np.abs(z), 1.5)
    assert np.all(on_side | on_cap) and np.all(np.hypot(x, y) <= 1 + 1e-12)
    # the polygonal cross-section is slightly inside the circle
    assert np.isclose(_signed_volume(s.vertices, s.faces), np.pi * 3.0, rtol=0.01)


def _check_planar_up(s):
    assert np.all(s.vertices[:, 2] == 0)
    v, f = s.vertices, s.faces
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(normals[:, 2] > 0)


def test_flat_disk():
    s = shapes.flat_disk(radius=1.0)
    check_mesh(s, closed=False, euler=1)
    _check_planar_up(s)
    assert 1200 <= len(s.faces) <= 1300
    assert np.all(np.hypot(*s.vertices[:, :2].T) <= 1 + 1e-12)
    v, f = s.vertices, s.faces
    area = 0.5 * np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, 2].sum()
    assert np.isclose(area, np.pi, rtol=0.01)      # inscribed 84-gon
    assert _face_angles_deg(s.vertices, s.faces).max() < 100


def test_square_patch():
    s = shapes.square_patch(n=24, jitter=0.2, seed=0)
    check_mesh(s, closed=False, euler=1)
    _check_planar_up(s)
    assert len(s.vertices) == 24 * 24 and len(s.faces) == 2 * 23 ** 2
    assert s.vertices[:, :2].min() == 0.0 and s.vertices[:, :2].max() == 1.0
    assert np.array_equal(shapes.square_patch(seed=0).vertices, s.vertices)
    assert not np.array_equal(shapes.square_patch(seed=1).vertices, s.vertices)


def test_hemisphere():
    s = shapes.hemisphere(level=4)
    check_mesh(s, closed=False, euler=1)
    assert len(s.faces) == 5120 // 2
    assert np.allclose(np.linalg.norm(s.vertices, axis=1), 1.0)
    v, f = s.vertices, s.faces
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", normals, v[f].mean(axis=1)) > 0)   # outward


#: The composites made ring by ring (surfaces of revolution); the implicit ones (quadruped,
#: fish) are checked in test_implicit.py.
REVOLVED = ("dumbbell", "three_blobs", "sphere_two_ellipsoids", "torus_chain")


@pytest.mark.parametrize("name", REVOLVED)
def test_builtin_composites(name):
    s = BUILTIN_SHAPES[name]()
    assert isinstance(s, Shape) and s.name == name
    euler = 0 if name == "torus_chain" else 2
    check_mesh(s, closed=True, euler=euler)
    assert 4000 <= len(s.faces) <= 20000
    assert np.all(_face_angles_deg(s.vertices, s.faces).max(axis=1) < 100)


def test_builtin_names():
    assert set(BUILTIN_SHAPES) == {"dumbbell", "three_blobs", "sphere_two_ellipsoids", "torus_chain",
                                   "quadruped", "fish"}


@pytest.mark.parametrize("make", [shapes.dumbbell, shapes.three_blobs])
def test_few_obtuse_triangles(make):
    s = make()
    assert np.mean(_face_angles_deg(s.vertices, s.faces).max(axis=1) > 100) < 0.05


def test_dumbbell_parts_and_neck():
    s = shapes.dumbbell(radius=1.0, center=1.08, neck=0.12)
    assert s.n_parts == 2
    centroid_z = s.vertices[s.faces, 2].mean(axis=1)
    assert np.array_equal(s.part_labels, (centroid_z > 0).astype(np.int64))
    r = np.hypot(*s.vertices[:, :2].T)
    z = s.vertices[:, 2]
    assert np.isclose(r[np.abs(z) < 0.05].min(), 0.12, rtol=0.01)
    # away from the neck the spheres are exact
    far = np.abs(z) > 0.6
    assert np.allclose(np.linalg.norm(s.vertices[far] - np.c_[0 * z, 0 * z, np.sign(z) * 1.08][far],
                                      axis=1), 1.0, atol=1e-6)


def test_three_blobs_necks():
    s = shapes.three_blobs()
    z, r = s.vertices[:, 2], np.hypot(*s.vertices[:, :2].T)
    centroid_z = s.vertices[s.faces, 2].mean(axis=1)
    # each label is one z-slab, the slabs in order bottom to top
    for lo, hi in zip(range(2), range(1, 3)):
        assert centroid_z[s.part_labels == lo].max() < centroid_z[s.part_labels == hi].min()
    # the split heights are necks of radius ~0.12
    for i in range(2):
        cut = (centroid_z[s.part_labels == i].max() + centroid_z[s.part_labels == i + 1].min()) / 2
        assert np.isclose(r[np.abs(z - cut) < 0.05].min(), 0.12, rtol=0.02)


def test_torus_chain_components():
    s = shapes.torus_chain(n=3)
    assert s.n_parts == 3 and _n_components(s) == 3
    for i in range(3):   # each component is one closed torus with its own label
        f = s.faces[s.part_labels == i]
        used, local = np.unique(f, return_inverse=True)
        part = Shape("part", s.vertices[used], local.reshape(-1, 3).astype(np.int64))
        check_mesh(part, closed=True, euler=0)
        assert _n_components(part) == 1
    sizes = [np.ptp(s.vertices[np.unique(s.faces[s.part_labels == i]), 2]) for i in range(3)]
    assert sizes[0] > sizes[1] > sizes[2]


def test_dumbbell_is_connected():
    assert _n_components(shapes.dumbbell()) == 1


def test_pinched_or_overlapping_profile_raises():
    with pytest.raises(ValueError):
        shapes.dumbbell(center=0.5, neck=0.12)     # overlapping spheres: neck too thin


@pytest.mark.parametrize("name", REVOLVED)     # slender along z, as the bound assumes
def test_bend_is_near_isometric(name):
    s = BUILTIN_SHAPES[name]()
    b = bend(s, angle=0.6)
    assert b.faces is not s.faces and np.array_equal(b.faces, s.faces)
    assert np.array_equal(b.part_labels, s.part_labels) and b.n_parts == s.n_parts
    e = _unique_edges(s.faces)
    before = np.linalg.norm(np.diff(s.vertices[e], axis=1)[:, 0], axis=1)
    after = np.linalg.norm(np.diff(b.vertices[e], axis=1)[:, 0], axis=1)
    change = np.abs(after / before - 1)
    z = s.vertices[:, 2]
    bound = 0.6 * np.abs(s.vertices[:, 0]).max() / np.ptp(z)   # documented worst case
    assert change.max() <= bound * 1.05
    assert change.mean() < 0.03
    assert _signed_volume(b.vertices, b.faces) == pytest.approx(_signed_volume(s.vertices, s.faces),
                                                                rel=0.02)
    # the vertices are really moved: the axis turns by the requested angle
    assert np.abs(b.vertices - s.vertices).max() > 0.1


def test_bend_maps_axis_to_arc_of_same_length():
    z = np.linspace(-2.0, 2.0, 401)
    axis = Shape("axis", np.c_[0 * z, 0 * z, z], np.zeros((0, 3), np.int64))
    p = bend(axis, angle=1.0).vertices
    assert np.isclose(np.linalg.norm(np.diff(p, axis=0), axis=1).sum(), 4.0, rtol=1e-4)
    ends = np.diff(p[[0, 1]], axis=0)[0], np.diff(p[[-2, -1]], axis=0)[0]
    turn = np.arccos(np.dot(*ends) / np.prod([np.linalg.norm(t) for t in ends]))
    assert np.isclose(turn, 1.0, atol=0.01)
    assert np.allclose(p[:, 1], 0.0)


def test_bend_zero_angle_is_identity():
    s = shapes.three_blobs()
    assert np.allclose(bend(s, angle=0.0).vertices, s.vertices)
