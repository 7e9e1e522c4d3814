"""Rays at any unit of length (:mod:`torchakvf.mesh.raycast`): the frame's power of two by hand,
first hits against the closed form on a box at scales from 1e-9 to 1e9 (where libigl's fixed
threshold loses them unscaled), bounded segments, and rays without a direction; segments tested
for a crossing by either engine against the closed form, and the two engines against each other
on a shape with a hole."""
import numpy as np
import pytest
import trimesh
from helpers.ray_engines import ENGINES

from torchakvf.errors import ParameterError
from torchakvf.mesh import raycast
from torchakvf.mesh.raycast import RayCaster, embree_available, ray_scale


def test_ray_scale_brings_the_mean_edge_near_one_by_a_power_of_two():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    mean = (2 + np.sqrt(2)) / 3                      # the mean of the edges 1, 1, sqrt(2)
    for s in (1.0, 3e-7, 0.01, 250.0, 1e9):
        k = ray_scale(v * s, f)
        assert k == 2.0 ** np.round(np.log2(k))       # a power of two
        assert 2 ** -0.5 <= k * s * mean < 2 ** 0.5
    assert ray_scale(v, np.zeros((0, 3), dtype=np.int64)) == 1.0
    assert ray_scale(np.zeros((3, 3)), f) == 1.0     # no edge of any length


@pytest.mark.parametrize("s", [1.0, 2.0 ** -20, 1e-3, 1e-9, 1e9])
def test_first_hits_on_a_box_at_any_scale(s):
    # a box [-1, 1] x [-0.5, 0.5] x [-0.25, 0.25] cut into 2 x 200 x 200 x 6 small faces: at
    # s = 1e-3 its faces' edges are 1e-5 and libigl alone misses every ray
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box = box.subdivide_to_size(0.01)
    v, f = np.asarray(box.vertices) * s, np.asarray(box.faces)
    rc = RayCaster(v, f)
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = rng.uniform(-0.2, 0.2, size=(200, 3)) * np.array([2.0, 1.0, 0.5])
    # the distance to the box's boundary along each unit ray, in closed form
    half = np.array([1.0, 0.5, 0.25])
    with np.errstate(divide="ignore"):
        exit_t = np.min(np.where(dirs > 0, (half - origin) / dirs, (-half - origin) / dirs), axis=1)
    face, t = rc.first_hit(origin * s, dirs)
    assert (face >= 0).all()
    # libigl returns the ray parameter in single precision
    np.testing.assert_allclose(t, exit_t * s, rtol=1e-6)
    # the same rays given as directions of any length: t counts in those directions' units
    face2, t2 = rc.first_hit(origin * s, dirs * 1e-6)
    np.testing.assert_array_equal(face2, face)
    np.testing.assert_allclose(t2, t * 1e6, rtol=1e-6)


def test_a_segment_is_blocked_only_by_a_face_before_its_end():
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0)).subdivide_to_size(0.5)
    rc = RayCaster(np.asarray(box.vertices) * 1e-4, np.asarray(box.faces))
    inside = np.array([[-0.5, 0, 0], [0.5, 0.1, 0.2]]) * 1e-4
    outside = np.array([[3.0, 0, 0], [0.0, -4.0, 0.5]]) * 1e-4
    # inside to inside: nothing before t = 1; inside to outside: the wall, at t < 1
    face, t = rc.first_hit(np.array([inside[0], inside[1]]),
                           np.array([inside[1] - inside[0], outside[1] - inside[1]]), max_t=1.0)
    assert face[0] == -1 and np.isinf(t[0])
    assert face[1] >= 0 and 0 < t[1] < 1
    # the second ray meets the wall y = -1 where 0.1 - 4.1 t = -1
    np.testing.assert_allclose(t[1], 1.1 / 4.1, rtol=1e-6)


def test_a_ray_without_a_direction_hits_nothing():
    box = trimesh.creation.box()
    rc = RayCaster(np.asarray(box.vertices), np.asarray(box.faces))
    face, t = rc.first_hit(np.zeros((2, 3)), np.array([[0.0, 0, 0], [1.0, 0, 0]]))
    assert face[0] == -1 and np.isinf(t[0])
    assert face[1] >= 0 and t[1] == pytest.approx(0.5)
    face, t = rc.first_hit(np.zeros((0, 3)), np.zeros((0, 3)))
    assert face.shape == (0,) and t.shape == (0,)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("s", [1.0, 2.0 ** -20, 1e-3, 1e-9, 1e9])
def test_segments_are_blocked_where_they_leave_a_box_at_any_scale(engine, s):
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5)).subdivide_to_size(0.05)
    rc = RayCaster(np.asarray(box.vertices) * s, np.asarray(box.faces), engine)
    assert rc.engine == engine
    rng = np.random.default_rng(1)
    half = np.array([1.0, 0.5, 0.25])
    p = rng.uniform(-0.9, 0.9, size=(500, 3)) * half
    q = rng.uniform(-1.6, 1.6, size=(500, 3)) * half
    # a convex box: the segment leaves it exactly where its far end lies outside; ends within
    # 1 % of a wall are left out (no round-off decides them)
    margin = np.min(np.abs(np.abs(q) - half) / half, axis=1)
    keep = margin > 0.01
    outside = (np.abs(q) > half).any(axis=1)
    got = rc.blocked(p * s, (q - p) * s)
    assert got.dtype == bool and got.shape == (500,)
    np.testing.assert_array_equal(got[keep], outside[keep])
    assert 100 < outside[keep].sum() < 400


@pytest.mark.parametrize("engine", ENGINES)
def test_a_segment_without_length_or_any_face_crosses_nothing(engine):
    box = trimesh.creation.box()
    rc = RayCaster(np.asarray(box.vertices), np.asarray(box.faces), engine)
    got = rc.blocked(np.zeros((2, 3)), np.array([[0.0, 0, 0], [1.0, 0, 0]]))
    assert got.tolist() == [False, True]
    assert rc.blocked(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    empty = RayCaster(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), engine)
    assert empty.blocked(np.zeros((1, 3)), np.ones((1, 3))).tolist() == [False]


@pytest.mark.skipif(not embree_available(), reason="embreex is not installed: nothing to compare libigl with")
def test_the_two_engines_agree_on_segments_inside_a_wheel():
    """A wheel (a rim, spokes and a hub: segments between its parts leave the solid through its
    holes) at a unit far from one: Embree in float32 and the tree in float64 give the same
    answer for every segment between points a little inside the surface, as the lines of sight
    place them."""
    from torchakvf.parts.creases import unit_face_normals
    from torchakvf.shapes.procedural import make_procedural

    shape = make_procedural("wheel", 5, detail=0.4).shape
    v, f = shape.vertices * 1e-3 + 7e-3, shape.faces
    inside = v[f].mean(axis=1) - 1e-4 * np.linalg.norm(np.ptp(v, axis=0)) * unit_face_normals(v, f)
    rng = np.random.default_rng(2)
    a, b = rng.integers(0, len(f), size=(2, 4000))
    p, d = inside[a], inside[b] - inside[a]
    by_tree = RayCaster(v, f, "libigl").blocked(p, d)
    by_embree = RayCaster(v, f, "embree").blocked(p, d)
    assert 100 < by_tree.sum() < 3900              # both answers occur
    np.testing.assert_array_equal(by_embree, by_tree)


def test_an_engine_that_is_not_there_is_named(monkeypatch):
    box = trimesh.creation.box()
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    with pytest.raises(ParameterError, match="engine must be one of"):
        RayCaster(v, f, "optix")
    monkeypatch.setattr(raycast, "embree_available", lambda: False)
    with pytest.raises(ParameterError, match="embreex"):
        RayCaster(v, f, "embree")
    assert RayCaster(v, f).engine == "libigl"      # "auto" falls back to the tree
