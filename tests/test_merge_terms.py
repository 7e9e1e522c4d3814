"""The merge decision's terms (:mod:`torchakvf.parts.merge_terms`): the shape diameter function
against closed forms, its rays fixed (same bits every call), each pair term by hand, and merging
states as adding their sums."""
from __future__ import annotations

import math

import numpy as np
import trimesh

from torchakvf.parts.merge_terms import TERM_NAMES, MergeState, cone_directions, face_thickness, pair_terms, part_sums


def test_cone_directions_are_unit_and_within_60_degrees_of_the_inward_normal():
    d = cone_directions(8)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert (-d[:, 2] >= math.cos(math.pi / 3) - 1e-12).all()
    np.testing.assert_array_equal(d, cone_directions(8))


def test_thickness_of_a_sphere_and_a_long_cylinder_against_closed_forms():
    # a chord of a sphere of radius r at angle θ to the inward normal is 2 r cos θ; over the
    # rays (cos θ uniform in [1/2, 1], the midpoints of 8 equal steps) its mean is 1.5 r
    r = 2.0
    s = trimesh.creation.icosphere(subdivisions=4, radius=r)
    t = face_thickness(s.vertices, s.faces, max_faces=500)
    assert np.isfinite(t).sum() == 500
    np.testing.assert_allclose(np.nanmedian(t), 1.5 * r, rtol=0.01)
    # a long cylinder of radius 0.25 is far thinner than the sphere: rays across it
    c = trimesh.creation.cylinder(radius=0.25, height=20.0, sections=64)
    tc = face_thickness(c.vertices, c.faces)
    side = np.abs(c.face_normals[:, 2]) < 0.1
    assert np.nanmedian(tc[side]) < 0.6 and np.nanmedian(tc[side]) > 0.25


def test_thickness_is_the_same_bits_every_call():
    s = trimesh.creation.capsule(height=1.0, radius=0.3)
    a, b = face_thickness(s.vertices, s.faces), face_thickness(s.vertices, s.faces)
    np.testing.assert_array_equal(a, b)


def test_thickness_in_any_unit_of_length():
    # a capsule 4 micrometres long: unscaled, libigl's fixed threshold let every ray through
    s = trimesh.creation.capsule(height=1.0, radius=0.3)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    t = face_thickness(v, f)
    assert np.isfinite(t).sum() == min(len(f), 1000)
    np.testing.assert_array_equal(face_thickness(v * 2.0 ** -18, f), t * 2.0 ** -18)
    np.testing.assert_allclose(face_thickness(v * 1e9, f), t * 1e9, rtol=1e-6)


def _state():
    # three parts in a row: 0 (area 1) - 1 (area 4) - 2 (area 1); 0 and 2 not adjacent
    length = np.array([[0, 1.0, 0], [1.0, 0, 2.0], [0, 2.0, 0]])
    concave = np.array([[0, 0.5, 0], [0.5, 0, 0], [0, 0, 0]])
    convex = np.zeros((3, 3))
    mean = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])
    return MergeState(area=np.array([1.0, 4.0, 1.0]), mean=mean, length=length, concave=concave, convex=convex,
                      thick=np.array([0.5, 8.0, 2.0]), thick_area=np.array([1.0, 4.0, 1.0]),
                      centroid=np.array([[3.0, 0, 0], [0, 0, 0], [-1.0, 0, 0]]), center=np.zeros(3),
                      radius=2.0, thick_median=1.0)


def test_pair_terms_by_hand():
    st = _state()
    T, adj = pair_terms(st, np.array([0, 1]), k=3)
    np.testing.assert_array_equal(adj, [[False, True, False], [True, False, True]])
    col = {n: i for i, n in enumerate(TERM_NAMES)}
    t01 = T[0, 1]
    assert t01[col["symmetry"]] == 1.0                          # orthogonal mean features
    assert t01[col["concavity"]] == 0.5                         # 0.5 / length 1
    # perimeters: 1, 3, 2 -> share 1 - 1 / min(1, 3) = 0
    assert t01[col["share"]] == 0.0
    np.testing.assert_allclose(t01[col["small"]], 1 * 3 / 6)   # min area x k / A
    np.testing.assert_allclose(t01[col["size_ratio"]], math.log(4))
    np.testing.assert_allclose(t01[col["short_cut"]], math.log(1 / 1))
    # thickness t = (0.5, 2, 2): |log(0.5 / 2)|; the smaller part (0) against the median 1
    np.testing.assert_allclose(t01[col["thickness"]], math.log(4))
    np.testing.assert_allclose(t01[col["thin"]], math.log(0.5))
    # centroids at distances 3/2 (part 0: 3 / area 1 / R 2) and 0: the smaller lies further out
    np.testing.assert_allclose(t01[col["centricity"]], 1.5)
    t12 = T[1, 2]
    np.testing.assert_allclose(t12[col["short_cut"]], math.log(2 / 1))
    np.testing.assert_allclose(t12[col["centricity"]], 0.5)     # part 2 (smaller): |(-1, 0, 0)| / 2
    np.testing.assert_array_equal(T[0, 2], 0.0)                 # not adjacent: all terms 0


def test_merging_a_state_adds_its_sums_and_the_terms_follow():
    st = _state()
    st.merge(0, 1)
    np.testing.assert_allclose(st.area, [5.0, 0.0, 1.0])
    np.testing.assert_allclose(st.mean[0], [0.2, 0.8])
    np.testing.assert_allclose(st.length, [[0, 0, 2.0], [0, 0, 0], [2.0, 0, 0]])
    np.testing.assert_allclose(st.thick, [8.5, 0, 2.0])
    np.testing.assert_allclose(st.centroid[0], [3.0, 0, 0])
    T, adj = pair_terms(st, np.array([0]), k=2)
    assert adj[0].tolist() == [False, False, True]
    col = {n: i for i, n in enumerate(TERM_NAMES)}
    np.testing.assert_allclose(T[0, 2, col["thickness"]], abs(math.log(8.5 / 5 / 2.0)))


def test_sight_term_is_the_share_of_blocked_lines_and_merges_add_counts():
    st = _state()
    col = TERM_NAMES.index("sight")
    np.testing.assert_array_equal(pair_terms(st, np.array([0, 1]), k=3)[0][..., col], 0.0)   # no counts: 0
    excess = TERM_NAMES.index("sight_excess")
    # the diagonal: a part's own segments (28 between 8 samples); part 0 sees all of itself,
    # part 1 half, part 2 a quarter
    st.seen = np.array([[28, 48, 10], [48, 14, 16], [10, 16, 7]], dtype=np.float64)
    st.lines = np.array([[28, 64, 64], [64, 28, 64], [64, 64, 28]], dtype=np.float64)
    T, _ = pair_terms(st, np.array([0, 1]), k=3)
    np.testing.assert_allclose(T[0, 1, col], 1 - 48 / 64)
    np.testing.assert_allclose(T[1, 2, col], 1 - 16 / 64)
    np.testing.assert_allclose(T[0, 1, excess], (1 - 48 / 64) - (0 + 0.5) / 2)
    np.testing.assert_allclose(T[1, 2, excess], (1 - 16 / 64) - (0.5 + 0.75) / 2)
    assert T[0, 2, col] == T[0, 2, excess] == 0.0                   # not adjacent
    st.merge(0, 1)
    np.testing.assert_array_equal(st.seen[0], [28 + 14 + 48, 0, 26])
    np.testing.assert_array_equal(st.lines[:, 0], [28 + 28 + 64, 0, 128])
    T, _ = pair_terms(st, np.array([0]), k=2)
    np.testing.assert_allclose(T[0, 2, col], 1 - 26 / 128)
    np.testing.assert_allclose(T[0, 2, excess], (1 - 26 / 128) - ((1 - 90 / 120) + 0.75) / 2)


def test_part_sums_of_labelled_faces():
    labels = np.array([0, 0, 1, -1])
    area = np.array([1.0, 3.0, 2.0, 5.0])
    cent = np.array([[0, 0, 0], [4.0, 0, 0], [0, 3.0, 0], [9.0, 9.0, 9.0]])
    thick = np.array([1.0, np.nan, 3.0, 7.0])
    s = part_sums(labels, 2, area, cent, thick)
    np.testing.assert_allclose(s["centroid"], [[12.0, 0, 0], [0, 6.0, 0]])
    np.testing.assert_allclose(s["center"], [2.0, 1.0, 0])      # the unlabelled face left out
    np.testing.assert_allclose(s["thick"], [1.0, 6.0])          # NaN left out
    np.testing.assert_allclose(s["thick_area"], [1.0, 2.0])
    assert s["thick_median"] == 2.0


def test_thickness_on_a_given_ray_caster_is_the_same_bits():
    from torchakvf.mesh.raycast import RayCaster

    s = trimesh.creation.capsule(height=1.0, radius=0.3)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    np.testing.assert_array_equal(face_thickness(v, f, caster=RayCaster(v, f)), face_thickness(v, f))


def test_flatness_of_a_state_and_its_merges_by_hand():
    """|Σ a n| / Σ a: a plane patch 1, two patches facing apart 0, at right angles √2 / 2; a
    merge adds the vector areas; an emptied part reads 0; no vector areas: None."""
    st = _state()
    assert st.flatness() is None
    st.vector_area = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]])   # areas 1, 4, 1
    np.testing.assert_allclose(st.flatness(), [1.0, 0.25, 1.0])
    st.merge(1, 2)
    np.testing.assert_allclose(st.vector_area, [[0, 0, 1.0], [1.0, 0, -1.0], [0, 0, 0]])
    np.testing.assert_allclose(st.flatness(), [1.0, math.sqrt(2) / 5, 0.0])
    st.merge(0, 1)
    np.testing.assert_allclose(st.flatness(), [1.0 / 6, 0.0, 0.0])
