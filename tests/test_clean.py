"""The clean-up of a mesh (merge, drop, re-orient, components, outliers) with its maps back to
the input's faces, and the topology it refuses with a MeshError naming the mesh."""
from __future__ import annotations

import re

import numpy as np
import pytest
from helpers.meshfiles import off_text
from helpers.refusals import write_file

import torchakvf as ta
from torchakvf import shapes
from torchakvf.mesh.clean import OUTLIER_DISTANCE, faces_at_outliers, weld_roots

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def _akvf_eigs(mesh, n=12):
    return ta.akvf(mesh, n=n).eigenvalues[0].numpy()


def _moebius(n=24, twisted=True):
    t = 2 * np.pi * np.arange(n) / n
    centre = np.c_[np.cos(t), np.sin(t), 0 * t]
    if twisted:
        d = 0.3 * np.c_[np.cos(t / 2) * np.cos(t), np.cos(t / 2) * np.sin(t), np.sin(t / 2)]
    else:
        d = 0.3 * np.c_[0 * t, 0 * t, np.ones(n)]
    vertices = np.vstack([centre + d, centre - d])
    a, b = np.arange(n), np.arange(n) + n
    faces = []
    for i in range(n):
        if i < n - 1:
            faces += [[a[i], b[i], a[i + 1]], [a[i + 1], b[i], b[i + 1]]]
        elif twisted:  # after a half turn the strip's sides are swapped
            faces += [[a[i], b[i], b[0]], [b[0], b[i], a[0]]]
        else:
            faces += [[a[i], b[i], a[0]], [a[0], b[i], b[0]]]
    return vertices, np.array(faces)


@pytest.mark.parametrize("case", ["non_manifold", "moebius"])
def test_bad_topology_in_file_raises_on_cleaning(tmp_path, case):
    if case == "non_manifold":   # edge (0, 1) shared by 3 faces
        V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
        F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
        problem = r"non-manifold edge .* 3 faces"
    else:
        V, F = _moebius()
        problem = r"not orientable"
    path = write_file(tmp_path / f"{case}.off", off_text(V, F))
    mesh = ta.load_mesh(path)          # parses fine: the topology is checked by the clean-up
    for call in (ta.clean_mesh, lambda m: ta.akvf(m, n=4)):
        with pytest.raises(ta.MeshError) as info:
            call(mesh)
        assert info.value.source == str(path)
        assert re.search(problem, info.value.problem), info.value.problem


def test_untwisted_strip_is_accepted():
    """Control for the Moebius case: the same strip without the twist is an orientable annulus."""
    V, F = _moebius(twisted=False)
    c = ta.clean_mesh(ta.Mesh(V, F, "annulus"))
    assert c.report["boundary_edges"] == 48 and c.report["flipped_faces"] == 0


def test_non_manifold_message_uses_input_vertex_indices():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(ta.MeshError) as info:
        ta.clean_mesh(ta.Mesh(V, F, "nm"))
    assert "(0, 1)" in info.value.problem, info.value.problem


def test_everything_degenerate_raises():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    with pytest.raises(ta.MeshError, match=r"^flat: .*repeat"):
        ta.clean_mesh(ta.Mesh(V, np.array([[0, 0, 1], [1, 2, 2]]), "flat"))
    with pytest.raises(ta.MeshError, match=r"^line: .*zero area"):
        ta.clean_mesh(ta.Mesh(V, np.array([[0, 1, 2]]), "line"))


# ---------------------------------------------------------------------------------------------
# cleaning
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ico3():
    s = shapes.icosphere(3)
    return s.vertices, s.faces


@pytest.fixture(scope="module")
def ico3_eigs(ico3):
    return _akvf_eigs(ta.Mesh(*ico3))


def test_clean_mesh_is_identity_on_a_good_mesh(ico3):
    V, F = ico3
    c = ta.clean_mesh(ta.Mesh(V, F))
    assert c.report == {"merged_vertices": 0, "welded_vertices": 0, "repeated_index_faces": 0, "outlier_faces": 0,
                        "zero_area_faces": 0,
                        "repeated_faces": 0, "split_edges": 0, "unreferenced_vertices": 0, "flipped_faces": 0,
                        "turned_outward": 0, "components": 1, "boundary_edges": 0}
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))
    assert c.n_input_faces == len(F) and c.n_components == 1
    # same triangles (vertices may be renumbered)
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])


def test_triangle_soup_merges_to_the_indexed_spectrum(ico3, ico3_eigs):
    V, F = ico3
    soup = ta.Mesh(V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3), "soup")
    c = ta.clean_mesh(soup)
    assert c.report["merged_vertices"] == 3 * len(F) - len(V)
    assert len(c.vertices) == len(V) and len(c.faces) == len(F)
    np.testing.assert_allclose(_akvf_eigs(soup), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_unreferenced_vertices_removed(ico3, ico3_eigs):
    V, F = ico3
    extra = np.array([[5.0, 5.0, 5.0], [-3.0, 1.0, 2.0], [0.1, 0.2, 0.3]])
    # put two of the extra vertices first so every face index moves
    V2 = np.vstack([extra[:2], V, extra[2:]])
    mesh = ta.Mesh(V2, F + 2)
    c = ta.clean_mesh(mesh)
    assert c.report["unreferenced_vertices"] == 3
    assert len(c.vertices) == len(V)
    # The kept vertices (in the merge's lexicographic order), the faces renumbered onto them.
    np.testing.assert_array_equal(c.vertices, np.unique(V, axis=0))
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])
    np.testing.assert_allclose(_akvf_eigs(mesh), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_renumbering_and_orientation_with_unreferenced_vertices_scattered(ico3):
    # Unreferenced vertices among the used ones and flipped faces: the clean mesh's vertices are
    # the referenced ones (in the duplicate merge's order), every edge's two faces traverse it
    # in opposite directions, and each face is its input face up to the flip.
    V, F = ico3
    rng = np.random.default_rng(7)
    order = rng.permutation(len(V) + 9)
    V2 = np.vstack([V, rng.random((9, 3)) + 3.0])[np.argsort(order)]
    F2 = order[F]
    F2[::3] = F2[::3, ::-1]
    c = ta.clean_mesh(ta.Mesh(V2, F2))
    # The vertices the faces use, in the duplicate merge's (lexicographic) order.
    np.testing.assert_array_equal(c.vertices, np.unique(V2[np.unique(F2)], axis=0))
    assert c.report["unreferenced_vertices"] == 9
    input_id = {tuple(v): i for i, v in enumerate(V2.tolist())}
    ids = np.array([input_id[tuple(v)] for v in c.vertices.tolist()])[c.faces]
    np.testing.assert_array_equal(c.face_index, np.arange(len(F2)))
    np.testing.assert_array_equal(np.sort(ids, axis=1), np.sort(F2, axis=1))
    assert c.report["flipped_faces"] in (len(F2[::3]), len(F2) - len(F2[::3]))
    half = np.stack([c.faces, c.faces[:, [1, 2, 0]]], axis=2).reshape(-1, 2)
    assert len({tuple(h) for h in half.tolist()}) == len(half)      # no half-edge twice


def test_degenerate_faces_dropped_outputs_sized_to_input(ico3):
    V, F = ico3
    nv = len(V)
    a, b = F[100, 0], F[100, 1]
    mid = 0.5 * (V[a] + V[b])                          # collinear with the edge a-b
    V2 = np.vstack([V, mid])
    bad = np.array([[a, a, b],                         # repeated index
                    [a, nv, b],                        # zero area
                    [F[5, 0], F[5, 1], F[5, 1]],       # repeated index elsewhere
                    F[200]])                           # the same face twice
    insert_at = np.array([10, 11, 600, 900])
    F2 = F.copy()
    for pos, face in zip(insert_at, bad):
        F2 = np.insert(F2, pos, face, axis=0)
    np.testing.assert_array_equal(F2[insert_at], bad)
    mesh = ta.Mesh(V2, F2, "dirty")
    c = ta.clean_mesh(mesh)
    assert c.report["repeated_index_faces"] == 2
    assert c.report["zero_area_faces"] == 1
    assert c.report["repeated_faces"] == 1
    assert c.report["unreferenced_vertices"] == 1      # the midpoint, only used by the dropped face
    assert c.n_input_faces == len(F2) and len(c.faces) == len(F)
    kept = np.setdiff1d(np.arange(len(F2)), insert_at)
    np.testing.assert_array_equal(c.face_index, kept)

    res = ta.akvf(mesh, n=6)
    clean_res = ta.akvf(ta.Mesh(V, F), n=6)
    np.testing.assert_allclose(res.eigenvalues.numpy(), clean_res.eigenvalues.numpy(),
                               rtol=1e-9, atol=1e-10)
    fv = res.mesh_face_vectors(0)
    assert fv.shape == (len(F2), 6, 3)
    assert np.all(fv[insert_at] == 0)
    assert np.all(np.linalg.norm(fv[kept], axis=-1) > 0)
    # per-face norms land on the right input faces: compare |X| summed over a cluster (basis-free)
    ref_fv = clean_res.mesh_face_vectors(0)
    np.testing.assert_allclose((fv[kept, 3:6] ** 2).sum(axis=(1, 2)),
                               (ref_fv[:, 3:6] ** 2).sum(axis=(1, 2)), rtol=1e-6, atol=1e-10)

    # labels: the kept faces of the cleaned mesh get labels by the sign of their centroid's z;
    # every dropped face lies where all faces around it carry one label, and takes it.
    cz = c.vertices[c.faces].mean(axis=1)[:, 2]
    labels = (cz > 0).astype(np.int64)
    out = c.labels_to_input_faces(labels)
    assert out.shape == (len(F2),)
    np.testing.assert_array_equal(out[kept], labels)
    for f in insert_at:
        touching = np.isin(F2[kept], F2[f]).any(axis=1)
        neighbour_labels = out[kept][touching]
        assert len(neighbour_labels) > 0
        assert out[f] == np.bincount(neighbour_labels).argmax()
    # to_input_faces fills dropped faces
    filled = c.to_input_faces(np.arange(len(c.faces)) + 1, fill=-7)
    assert np.all(filled[insert_at] == -7)
    np.testing.assert_array_equal(filled[kept], np.arange(len(c.faces)) + 1)


def test_labels_of_dropped_face_follow_its_neighbours():
    """A dropped sliver between two label regions takes the majority label of the faces touching it."""
    s = shapes.flat_disk()
    V, F = s.vertices, s.faces
    # a zero-area face on an interior edge: (a, midpoint, b)
    a, b = F[50, 0], F[50, 1]
    V2 = np.vstack([V, 0.5 * (V[a] + V[b])])
    F2 = np.vstack([F, [[a, len(V), b]]])
    c = ta.clean_mesh(ta.Mesh(V2, F2))
    assert c.report["zero_area_faces"] == 1
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))   # cleaned face i = input face i
    labels = np.zeros(len(c.faces), dtype=np.int64)
    touch_a = np.isin(F, a).any(axis=1)
    touch_b_only = np.isin(F, b).any(axis=1) & ~touch_a
    labels[touch_a] = 5
    labels[touch_b_only] = 3
    assert touch_a.sum() > touch_b_only.sum()          # label 5 is the majority around the sliver
    out = c.labels_to_input_faces(labels)
    np.testing.assert_array_equal(out[:-1], labels)
    assert out[-1] == 5, (out[-1], touch_a.sum(), touch_b_only.sum())


def test_inconsistent_orientation_repaired(ico3, ico3_eigs):
    V, F = ico3
    F2 = F.copy()
    flip = np.zeros(len(F), bool)
    flip[1::2] = True                                   # half the faces, face 0 kept
    F2[flip] = F2[flip][:, ::-1]
    mesh = ta.Mesh(V, F2, "flipped")
    c = ta.clean_mesh(mesh)
    assert c.report["flipped_faces"] == int(flip.sum())
    # the cleaned faces are the original (outward) ones again
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])
    np.testing.assert_allclose(_akvf_eigs(mesh), ico3_eigs, rtol=1e-9, atol=1e-10)

    # flipping face 0 too: made consistent, the mesh is inward, and it is turned outward again
    F3 = F.copy()
    F3[0::2] = F3[0::2][:, ::-1]
    c3 = ta.clean_mesh(ta.Mesh(V, F3))
    assert c3.report["flipped_faces"] == len(F) // 2 and c3.report["turned_outward"] == len(F)
    np.testing.assert_array_equal(c3.vertices[c3.faces], V[F])
    np.testing.assert_allclose(_akvf_eigs(ta.Mesh(V, F3)), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_two_components_union_spectrum():
    """Two disjoint spheres of different radii and meshes: the spectrum is the union of the
    components' spectra, each rescaled from its own area to the total area."""
    s1 = shapes.icosphere(3, radius=1.0)
    s2 = shapes.icosphere(2, radius=2.0)
    V = np.vstack([s1.vertices, s2.vertices + [5.0, 0.0, 0.0]])
    F = np.vstack([s1.faces, s2.faces + len(s1.vertices)])
    mesh = ta.Mesh(V, F, "two spheres")
    c = ta.clean_mesh(mesh)
    assert c.report["components"] == 2 and c.n_components == 2
    comp_faces = np.bincount(c.face_component)
    assert sorted(comp_faces.tolist()) == sorted([len(s1.faces), len(s2.faces)])

    def area(v, f):
        p = v[f]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()

    a1, a2 = area(s1.vertices, s1.faces), area(s2.vertices, s2.faces)
    n = 16
    mu1 = ta.akvf(ta.Mesh(s1.vertices, s1.faces), n=n, remedy="none").eigenvalues[0].numpy()
    mu2 = ta.akvf(ta.Mesh(s2.vertices, s2.faces), n=n, remedy="none").eigenvalues[0].numpy()
    # lambda_phys = mu_c / A_c; reported lambda_phys * A_total
    union = np.sort(np.r_[mu1 * (a1 + a2) / a1, mu2 * (a1 + a2) / a2])[:n]
    both = ta.akvf(mesh, n=n, remedy="none").eigenvalues[0].numpy()
    np.testing.assert_allclose(both, union, rtol=1e-6)
    # both components contribute their 3 rotations: 6 small eigenvalues, then a gap
    assert np.all(both[:6] < 0.1) and both[6] > 5


def _signed_volumes(c):
    p = c.vertices[c.faces]
    return np.bincount(c.face_component, weights=np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))) / 6


def test_closed_surfaces_are_turned_outward_cavities_and_open_ones_kept():
    s = shapes.icosphere(2)
    v, f = s.vertices, s.faces
    inward = ta.clean_mesh(ta.Mesh(v, f[:, ::-1], name="inward"))
    assert inward.report["turned_outward"] == len(f) and inward.report["flipped_faces"] == 0
    np.testing.assert_array_equal(inward.faces, ta.clean_mesh(ta.Mesh(v, f)).faces)
    assert _signed_volumes(inward)[0] > 0
    # a solid ball with a cavity: the inner sphere faces the cavity (inward) and stays so
    hollow = ta.clean_mesh(ta.Mesh(np.concatenate([v, 0.5 * v]), np.concatenate([f, f[:, ::-1] + len(v)])))
    assert hollow.report["turned_outward"] == 0 and (np.sign(_signed_volumes(hollow)) == [1, -1]).all()
    # two balls side by side, the second inward: only it is turned
    apart = ta.clean_mesh(ta.Mesh(np.concatenate([v, v + 3.0]), np.concatenate([f, f[:, ::-1] + len(v)])))
    assert apart.report["turned_outward"] == len(f) and (_signed_volumes(apart) > 0).all()
    # an open cap has no inside: kept as it is, either way round
    cap = f[(v[f].mean(axis=1)[:, 2] > 0.3)]
    for faces in (cap, cap[:, ::-1]):
        assert ta.clean_mesh(ta.Mesh(v, faces)).report["turned_outward"] == 0


def test_an_inward_mesh_segments_as_the_outward_one():
    """The merge reads concave creases, lines of sight and thickness, all of which turn inside
    out with the faces: an inward U was cut elsewhere before it was turned outward."""
    from helpers.voxel_meshes import voxel_u

    v, f, _, _ = voxel_u()
    out = ta.segment([ta.Mesh(v, f)], k=3, seed=0)[0].labels
    inward = ta.segment([ta.Mesh(v, f[:, ::-1])], k=3, seed=0)[0].labels
    np.testing.assert_array_equal(inward, out)


def test_weld_roots_by_hand():
    v = np.array([[0, 0, 0], [1e-15, 0, 0], [1, 0, 0], [0, 1, 0], [2e-15, 1e-15, 0], [0, 0, 1.0]])
    # 0, 1 and 4 lie within round-off of each other: all welded into the lowest, 0
    np.testing.assert_array_equal(weld_roots(v), [0, 0, 2, 3, 0, 5])
    assert weld_roots(v[[0, 2, 3, 5]]) is None                 # nothing that close
    # A stray coordinate does not set the scale: on the bounding box's diagonal (1e12) the
    # tolerance would be 100 and weld the unit-spaced vertices together.
    far = np.concatenate([v[[0, 2, 3, 5]], [[1e12, 0, 0]]])
    assert weld_roots(far) is None


def test_marching_cubes_disc_on_a_grid_plane_stays_one_closed_surface():
    """A slab whose face lies on a grid plane: marching cubes puts pairs of vertices 1e-15
    apart there, with zero-area faces between them. Dropped without a weld, they cut the
    disc's top from its rim (2 components, open); welded, the surface stays closed."""
    from torchakvf.shapes.marching import marching_cubes
    from torchakvf.shapes.sdf import cylinder

    disc = cylinder((0, 0, -0.1), (0, 0, 0.1), 1.0)
    v, f = marching_cubes(disc, (-1.1, -1.1, -0.2), (1.1, 1.1, 0.2), 0.03)   # z = 0.1 on the grid
    # the near-duplicates are there: distinct vertices, equal to 9 decimals
    assert len(np.unique(v, axis=0)) == len(v) > len(np.unique(v.round(9), axis=0))
    c = ta.clean_mesh(ta.Mesh(v, f, name="disc"))
    assert c.report["welded_vertices"] > 0 and c.report["repeated_index_faces"] > 0
    assert c.report["components"] == 1 and c.report["boundary_edges"] == 0
    assert c.report["zero_area_faces"] == 0
    # the welded surface has the disc's area (2 pi r^2 + 2 pi r h), to the grid's resolution
    area = ta.mesh.face_areas(c.vertices, c.faces).sum()
    assert abs(area - (2 * np.pi + 2 * np.pi * 0.2)) < 0.02 * area
    # every input face maps to a kept face or is one of the dropped slivers
    assert len(c.faces) + c.report["repeated_index_faces"] == len(f)
    # without the weld (as decimated meshes are cleaned) the slivers are dropped and the
    # surface comes apart along the plane
    plain = ta.clean_mesh(ta.Mesh(v, f, name="disc"), weld=False)
    assert plain.report["welded_vertices"] == 0 and plain.report["zero_area_faces"] > 0
    assert plain.report["components"] == 2 and plain.report["boundary_edges"] > 0


def _outward_tetrahedron(p: np.ndarray, ids: list) -> list:
    """The four faces of the tetrahedron on points ids of p, each counter-clockwise from outside."""
    out = []
    for k in range(4):
        tri = [ids[i] for i in range(4) if i != k]
        n = np.cross(p[tri[1]] - p[tri[0]], p[tri[2]] - p[tri[0]])
        out.append(tri if n @ (p[tri[0]] - p[ids[k]]) > 0 else tri[::-1])
    return out


def test_two_solids_touching_along_an_edge_are_split_there():
    """Two tetrahedra on opposite sides of the edge (0, 1) they share: four faces on it,
    alternating in direction around it. Each face is paired across its own solid's wedge and
    the edge's vertices copied, so the two closed surfaces come apart there (two components, no
    opening); pairing across the empty wedges would have made one surface."""
    p = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 0.5, 1], [0.5, -1, 0], [0.5, -0.5, -1.0]])
    f = np.array(_outward_tetrahedron(p, [0, 1, 2, 3]) + _outward_tetrahedron(p, [0, 1, 4, 5]))
    c = ta.clean_mesh(ta.Mesh(p, f, name="pair"))
    assert c.report["split_edges"] == 1
    assert len(c.vertices) == 8 and c.report["boundary_edges"] == 0
    assert c.report["components"] == 2
    np.testing.assert_array_equal(np.bincount(c.face_component), [4, 4])
    # each component is one whole tetrahedron of the input, its faces where they were
    for comp in range(2):
        rows = c.face_index[c.face_component == comp]
        assert set(rows.tolist()) in ({0, 1, 2, 3}, {4, 5, 6, 7})
    np.testing.assert_allclose(np.sort(c.vertices[c.faces].reshape(-1, 9), axis=0),
                               np.sort(p[f][c.face_index].reshape(-1, 9), axis=0))
    # a mesh without such edges is untouched
    assert ta.clean_mesh(ta.Mesh(p, f[:4], name="one")).report["split_edges"] == 0


def test_a_marching_cubes_mug_whose_thin_handle_touches_along_edges_is_segmented():
    """A cylinder with a ring handle 0.12 thick, meshed by marching cubes at a 0.04 grid: the
    handle is three cells thick, and its surface touches itself along two edges of four faces.
    Refused, the whole shape would be lost; split, it is one closed surface and segments into
    body and handle."""
    from torchakvf.evaluate.metrics import rand_index_error
    from torchakvf.shapes.marching import marching_cubes
    from torchakvf.shapes.sdf import Torus, Union, cylinder, frame, union_bounds

    parts = (cylinder((0, 0, 0), (0, 0, 1.0), 0.4),
             Torus(center=(0.5, 0, 0.5), rotation=frame((0, 1, 0)), major=0.25, minor=0.06))
    lo, hi = union_bounds(parts)
    v, f = marching_cubes(Union(parts), lo - 0.08, hi + 0.08, 0.04)
    c = ta.clean_mesh(ta.Mesh(v, f, name="mug"))
    assert c.report["split_edges"] == 2           # two edges of four faces, each split in two
    assert c.report["components"] == 1 and c.report["boundary_edges"] == 0
    truth = np.stack([p(v[f].mean(axis=1)) for p in parts], axis=1).argmin(axis=1)
    labels = ta.segment([ta.Mesh(v, f, name="mug")], k=2, seed=0, coarse_faces=4000)[0].labels
    assert rand_index_error(labels, truth) < 0.05


def _sphere_with_a_needle():
    """icosphere(2) with one edge (A, C) split at its midpoint B on one side only, and the
    needle face (A, C, B) of zero area closing the other side (as on PSB 351)."""
    s = shapes.icosphere(2)
    v, f = s.vertices.copy(), s.faces.copy()
    a, c = int(f[0, 0]), int(f[0, 1])
    x = int(f[0, 2])
    b = len(v)
    v = np.concatenate([v, (v[a] + v[c])[None] / 2])
    f = np.concatenate([f[1:], [[a, b, x], [b, c, x], [a, c, b]]])
    return s, ta.Mesh(v, f, name="needle")


def test_zip_cracks_closes_the_hole_a_needle_face_leaves():
    s, mesh = _sphere_with_a_needle()
    plain = ta.clean_mesh(mesh, zip_cracks=False)
    assert plain.report["zero_area_faces"] == 1 and plain.report["boundary_edges"] == 3   # a crack
    zipped = ta.clean_mesh(mesh)                           # the default zips
    assert zipped.report["zipped_cracks"] == 1 and zipped.report["boundary_edges"] == 0
    assert len(zipped.faces) == len(s.faces) + 2           # the face across the crack is split
    area = ta.mesh.face_areas(zipped.vertices, zipped.faces).sum()
    assert np.isclose(area, ta.mesh.face_areas(s.vertices, s.faces).sum())
    # Every kept face maps to an input face; both halves of the split face to the same one.
    assert np.bincount(zipped.face_index).max() == 2
    # A closed sphere again: its three rotations are Killing fields (λ·area near 0).
    lam = ta.akvf(zipped, n=4).eigenvalues[0].numpy()
    ref = ta.akvf(ta.Mesh(s.vertices, s.faces), n=4).eigenvalues[0].numpy()
    assert np.all(np.abs(lam[:3]) < 0.5) and lam[3] > 5 and np.allclose(lam, ref, rtol=0.2, atol=0.3)
    # Without zipping, the crack's boundary terms cost a rotation (2.36 against 0.12, measured).
    assert ta.akvf(plain, n=4).eigenvalues[0, 2] > 1.0


# ---------------------------------------------------------------------------------------------
# outliers
# ---------------------------------------------------------------------------------------------

def test_one_outlier_vertex_drops_only_its_faces():
    """A torus with one vertex moved to 1e12: the faces at it are dropped (and counted), the
    other faces are kept as they are, and every input face still gets a label."""
    t = shapes.torus()
    v = t.vertices.copy()
    v[5] = [1e12, 0.0, 0.0]
    at = np.flatnonzero((t.faces == 5).any(axis=1))
    c = ta.clean_mesh(ta.Mesh(v, t.faces, "stray"))
    assert c.report["outlier_faces"] == len(at) == 6
    assert c.report["zero_area_faces"] == 0 and c.report["unreferenced_vertices"] == 1
    np.testing.assert_array_equal(c.face_index, np.setdiff1d(np.arange(len(t.faces)), at))
    assert np.abs(c.vertices).max() < 10
    labels = (c.vertices[c.faces].mean(axis=1)[:, 0] > 0).astype(np.int64)
    out = c.labels_to_input_faces(labels)
    assert out.shape == (len(t.faces),) and (out >= 0).all()


def test_outlier_criterion_is_scale_free_and_spares_a_long_shape():
    t = shapes.torus()
    for scale in (1e-6, 1.0, 1e6):
        v = t.vertices * scale
        assert not faces_at_outliers(v, t.faces).any()
        v = v.copy()
        v[0] = v[0] + 10 * OUTLIER_DISTANCE * scale * np.array([1.0, 0.0, 0.0])
        assert faces_at_outliers(v, t.faces).sum() == (t.faces == 0).any(axis=1).sum()
    # a bar 100 times longer than wide: nothing is an outlier
    bar = shapes.icosphere(2)
    v = bar.vertices * np.array([100.0, 1.0, 1.0])
    assert not faces_at_outliers(v, bar.faces).any()
    # a small part far from the rest keeps its faces: their own edges are short
    big, small = shapes.icosphere(3), shapes.icosphere(1, radius=0.1)
    v = np.vstack([big.vertices, small.vertices + [1e5, 0.0, 0.0]])
    f = np.vstack([big.faces, small.faces + len(big.vertices)])
    assert not faces_at_outliers(v, f).any()
    c = ta.clean_mesh(ta.Mesh(v, f, "far"))
    assert c.report["outlier_faces"] == 0 and c.n_components == 2


def test_a_mesh_of_outliers_only_is_refused():
    """A fan whose every face has its apex far away: nothing is left."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 2, 0], [0, 0, 1e15]], float)
    f = np.array([[0, 1, 5], [1, 2, 5], [2, 3, 5], [3, 4, 5]])
    with pytest.raises(ta.MeshError, match=r"^few: .*outlier"):
        ta.clean_mesh(ta.Mesh(v, f, "few"))


def test_psb_meshes_have_no_outliers():
    import gzip
    import os
    from pathlib import Path

    from torchakvf.io.off import parse_off
    root = Path(os.environ.get("TORCHAKVF_PSB", Path(__file__).parents[2] / "shared" / "psb"))
    if not (root / "meshes").is_dir():
        pytest.skip(f"PSB not found at {root} (set TORCHAKVF_PSB)")
    for i in (1, 14, 30, 38, 260, 351):     # 30: the longest edge for its spread
        v, f = parse_off(gzip.decompress((root / "meshes" / f"{i}.off.gz").read_bytes()), str(i))
        assert not faces_at_outliers(v, f).any()
