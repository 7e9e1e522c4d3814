"""Coarse-to-fine solving (torchakvf.mesh.coarse): decimation, point location, results on the
original faces."""
from __future__ import annotations

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.evaluate.metrics import matched_agreement
from torchakvf.mesh import MeshBatch, clean_mesh, face_areas
from torchakvf.mesh.coarse import DECIMATE_SIZE, coarse_mesh, decimate, decimation_scale, drop_non_manifold

pytest.importorskip("fast_simplification")



def test_decimation_is_manifold_near_target_and_deterministic():
    s = shapes.icosphere(4)                                   # 5120 faces
    a = decimate(ta.Mesh(s.vertices, s.faces, name="ico"), 1000)
    b = decimate(ta.Mesh(s.vertices, s.faces, name="ico"), 1000)
    assert a.name == "ico"
    assert np.array_equal(a.faces, b.faces) and np.array_equal(a.vertices, b.vertices)
    c = clean_mesh(a)                                         # raises on non-manifold edges
    assert 900 <= len(c.faces) <= 1000
    assert c.report["components"] == 1 and c.report["boundary_edges"] == 0
    # Still a unit sphere: area and distance of the vertices from the center.
    assert abs(face_areas(c.vertices, c.faces).sum() / (4 * np.pi) - 1) < 0.02
    assert np.all(np.abs(np.linalg.norm(c.vertices, axis=1) - 1) < 0.02)
    with pytest.raises(ParameterError):
        decimate(ta.Mesh(s.vertices, s.faces), 2)


def test_decimation_scale_by_hand():
    assert DECIMATE_SIZE == (0.25, 8.0)
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0]])       # area 1: inside, left as it is
    f = np.array([[0, 1, 2]])
    assert decimation_scale(v, f) == 1.0
    assert decimation_scale(v * 0.25, f) == 1.0             # sqrt(area) 0.25: the lower bound
    assert decimation_scale(v * 7.9, f) == 1.0
    assert decimation_scale(v * 0.2, f) == 8.0              # outside: into [1, 2), 0.2 -> 1.6
    assert decimation_scale(v * 1e-3, f) == 1024.0          # 0.001 -> 1.024
    assert decimation_scale(v * 8.0, f) == 0.125            # 8 is past the upper bound -> 1
    assert decimation_scale(v * 250.0, f) == 2.0 ** -7      # -> 1.95
    assert decimation_scale(v, np.zeros((0, 3), dtype=np.int64)) == 1.0


def test_a_shape_decimates_alike_in_any_unit_of_length():
    # The collapse's thresholds are absolute: unscaled, the dumbbell at 2^-12 of its size
    # (sqrt(area) 0.0012) passes them all at once and collapses in sweep order. Outside
    # DECIMATE_SIZE a mesh is collapsed scaled by a power of two to a size in [1, 2): the copies
    # at 2^-12 and 2^12 of the dumbbell (5.0) exactly as the one at 2^-2 (1.25).
    s = shapes.dumbbell()
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    b = decimate(ta.Mesh(v * 0.25, f), 2000)
    for scale in (2.0 ** -12, 2.0 ** 12):
        a = decimate(ta.Mesh(v * scale, f), 2000)
        assert np.array_equal(a.faces, b.faces)
        assert np.array_equal(a.vertices, b.vertices * (scale / 0.25))


def test_faces_on_edges_with_three_faces_are_removed():
    # A fin: triangles (0,1,2), (1,0,3) and (0,1,4) all share edge (0, 1).
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5]])
    assert drop_non_manifold(f).tolist() == [[2, 1, 5]]


def test_small_meshes_are_not_decimated():
    s = shapes.icosphere(2)                                   # 320 faces
    assert coarse_mesh(ta.Mesh(s.vertices, s.faces), 300) is None
    batch = MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)], coarse_faces=300)
    assert batch.coarse_of(0) is None and batch.input_mesh(0) is batch.meshes[0]


def test_coarse_sphere_keeps_its_rotations():
    # The unit-area sphere's three rotations have eigenvalue ~0 and the next ones ~8π
    # (docs/akvf_operator.md, Sec. 3.1): decimated to 1500 faces and solved with the default
    # remedy, as the segmentation does, the rotations must stay far below the rest (without
    # the relaxation after decimation they are at 31).
    from torchakvf.parts import DEFAULT_REMEDY

    s = shapes.icosphere(4)
    fine = ta.akvf(ta.Mesh(s.vertices, s.faces), n=6, remedy=DEFAULT_REMEDY).eigenvalues[0].numpy()
    batch = MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)], coarse_faces=1500)
    coarse = ta.akvf(batch, n=6, remedy=DEFAULT_REMEDY).eigenvalues[0].numpy()
    assert np.all(np.abs(fine[:3]) < 0.05)
    assert np.all(np.abs(coarse[:3]) < 1.0), coarse
    assert np.all(coarse[3:] > 20.0) and np.allclose(coarse[3:], fine[3:], rtol=0.2), (coarse, fine)


@pytest.mark.parametrize("name", ["three_blobs", "sphere_two_ellipsoids"])
def test_coarse_segmentation_matches_true_parts_on_the_fine_faces(name):
    s = shapes.BUILTIN_SHAPES[name]()
    mesh = ta.Mesh(s.vertices, s.faces, name=name)
    seg = ta.segment(mesh, k=s.n_parts, coarse_faces=3000, seed=0, refine=True)
    m = seg[0]
    area = face_areas(s.vertices, s.faces)
    assert m.labels.shape == (len(s.faces),) and m.features.shape[0] == len(s.faces)
    assert m.params["coarse_faces"] <= 3000
    assert matched_agreement(m.labels, s.part_labels, area) >= 0.97
    # The refined mesh is cut at full resolution: it holds every input vertex.
    assert len(m.refined.vertices) >= len(s.vertices)
    assert seg.face_vectors(0).shape == (len(s.faces), m.params["n_fields"], 3)
    # The batch path (decimation carried by the MeshBatch) gives the same labels.
    batch = MeshBatch.from_meshes([mesh], coarse_faces=3000)
    assert batch.coarse_of(0) is not None and batch.input_mesh(0).n_input_faces == len(s.faces)
    again = ta.segment(batch, k=s.n_parts, seed=0, refine=False)
    assert np.array_equal(again[0].labels, m.labels)


def test_coarse_faces_needs_mesh_inputs():
    s = shapes.icosphere(2)
    batch = MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)])
    with pytest.raises(ParameterError, match="coarse_faces"):
        ta.segment(batch, k=2, coarse_faces=100)


def test_unique_rows_is_numpys_row_unique():
    from torchakvf.mesh.clean import unique_rows
    rng = np.random.default_rng(3)
    for a in [rng.integers(0, 4, size=(500, 3)), rng.integers(0, 3, size=(300, 2)).astype(np.float64),
              np.array([[0.0, -0.0, 1.0], [-0.0, 0.0, 1.0], [1.0, 2.0, 3.0], [0.0, 0.0, 1.0]])]:
        got = unique_rows(a)
        want = np.unique(a, axis=0, return_index=True, return_inverse=True, return_counts=True)
        for g, w in zip(got, want):
            assert np.array_equal(g, np.asarray(w).reshape(g.shape))


def test_boundary_loops_cut_a_boundary_through_a_vertex_twice():
    from torchakvf.mesh.coarse import boundary_loops
    eight = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [3, 4], [4, 0]])
    loops = boundary_loops(eight)
    assert sorted(sorted(loop) for loop in loops) == [[0, 1, 2], [0, 3, 4]]
    for loop in loops:   # each loop in boundary order
        assert all([a, b] in eight.tolist() for a, b in zip(loop, loop[1:] + loop[:1]))
    assert boundary_loops(np.array([[5, 6], [6, 7], [7, 5]])) == [[5, 6, 7]]
    assert boundary_loops(np.array([[0, 1], [1, 2]])) == []          # open: not a loop


def test_holes_touching_at_a_corner_are_closed():
    """Two faces of a vertex's star that share only that vertex, removed: the boundary passes
    the vertex twice. Both holes are closed (left open, the pinched loop's boundary terms make
    decimated PSB meshes unsolvable at every shift)."""
    from torchakvf.mesh.coarse import SurfaceIndex, fill_holes
    s = shapes.icosphere(2)
    star = np.flatnonzero((s.faces == 0).any(axis=1))                    # 5 faces around vertex 0
    first = star[0]
    apart = [g for g in star[1:] if len(set(s.faces[first]) & set(s.faces[g])) == 1]
    keep = np.setdiff1d(np.arange(len(s.faces)), [first, apart[0]])
    v, f = fill_holes(s.vertices, s.faces[keep], SurfaceIndex(s.vertices, s.faces), None)
    half = np.stack([f, f[:, [1, 2, 0]]], axis=2).reshape(-1, 2)     # the half-edges of f
    n = len(v)
    assert np.isin(half[:, 1] * n + half[:, 0], half[:, 0] * n + half[:, 1]).all()   # no boundary
    assert len(v) == len(s.vertices) + 2 and len(f) == len(s.faces) - 2 + 6             # two fans of 3
    batch = MeshBatch.from_meshes([ta.Mesh(v, f)])
    assert batch.meshes[0].report["boundary_edges"] == 0
    fields = ta.akvf(batch, n=4)
    assert float(fields.eigenvalues[0, 0]) > -1.0 and bool(fields.converged[0])


def test_psb_decimations_with_pinched_holes_are_closed_and_solvable(psb):
    """PSB 284 and 17 decimated to 4000 faces: the collapse leaves holes touching at a corner.
    Closed, the coarse mesh has no boundary and is solved decimated (left open, no shift
    factors it and the mesh falls back to full resolution: 76,476 edges for 284 instead of
    ~6,000)."""
    from torchakvf.fields.akvf import akvf_falling_back
    for mesh_id in (284, 17):
        batch = MeshBatch.from_meshes([ta.load_mesh(psb / "meshes" / f"{mesh_id}.off.gz")], coarse_faces=4000)
        assert batch.coarse_of(0) is not None
        assert batch.meshes[0].report["boundary_edges"] == 0
        fields, fell_back = akvf_falling_back(batch, n=8)
        assert fell_back == [] and int(fields.batch.edge_ptr[-1]) < 6100
        assert bool(fields.converged[0]) and float(fields.eigenvalues[0, 0]) > -1.0


def test_a_moved_renumbered_copy_decimates_canonically_to_the_same_surface():
    """canonical=True runs the collapse in a frame and numbering made from the surface
    (canonical_frame): the copy's coarse mesh is the coarse mesh moved, vertex for vertex."""
    from torchakvf.mesh.coarse import canonical_numbering
    s = shapes.fish()
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    pv, pf = rng.permutation(len(v)), rng.permutation(len(f))
    shift = np.array([1.0, -2.0, 0.5])
    a = clean_mesh(decimate(ta.Mesh(v, f), 2000, canonical=True))
    moved_v = v @ q.T + shift
    b = clean_mesh(decimate(ta.Mesh(moved_v[pv], np.argsort(pv)[f][pf]), 2000, canonical=True))
    assert len(a.faces) == len(b.faces)
    back = (b.vertices - shift) @ q
    np.testing.assert_allclose(np.sort(back, axis=0), np.sort(a.vertices, axis=0), atol=1e-9)
    # the same triangles, in the same canonical order
    ta_ = a.vertices[a.faces[canonical_numbering(a.vertices, a.faces)[2]]]
    tb = back[b.faces[canonical_numbering(b.vertices, b.faces)[2]]]
    np.testing.assert_allclose(np.sort(tb, axis=1), np.sort(ta_, axis=1), atol=1e-9)


def test_canonical_coarse_mesh_records_its_target():
    s = shapes.fish()
    c = coarse_mesh(ta.Mesh(s.vertices, s.faces), 2000, canonical=True)
    d = coarse_mesh(ta.Mesh(s.vertices, s.faces), 2000)
    assert c.canonical and not d.canonical and c.faces_asked == d.faces_asked == 2000
    assert abs(len(c.coarse.faces) - 2000) < 100
    # the same fine mesh; every fine face located on the canonical coarse surface
    assert c.fine.faces.shape == d.fine.faces.shape and np.all(c.faces_on_coarse.face < len(c.coarse.faces))


def test_canonical_frame_of_a_renumbered_sphere_is_the_same():
    """A sphere's principal moments are equal, so its frame is decided by round-off: the sums
    behind it are taken in an order set by the values, so that a renumbered copy (faces
    shuffled and rolled, vertices permuted) still gets the same frame, to the bit."""
    from torchakvf.mesh.coarse import canonical_frame
    s = shapes.icosphere(level=3)
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    rng = np.random.default_rng(1)
    pv, pf = rng.permutation(len(v)), rng.permutation(len(f))
    g = np.roll(np.argsort(pv)[f][pf], 1, axis=1)
    u0, g0, _ = canonical_frame(v, f)
    u1, g1, _ = canonical_frame(v[pv], g)
    np.testing.assert_array_equal(u1, u0)
    np.testing.assert_array_equal(g1, g0)


def _double_flange(h=0.03):
    """A disc 0.1 thick with a hub on each side, by marching cubes (21,064 faces at h = 0.03)."""
    from torchakvf.shapes.marching import marching_cubes
    from torchakvf.shapes.sdf import Union, cylinder

    parts = (cylinder((0, 0, -0.05), (0, 0, 0.05), 1.0), cylinder((0, 0, 0.05), (0, 0, 0.65), 0.25),
             cylinder((0, 0, -0.65), (0, 0, -0.05), 0.25))
    v, f = marching_cubes(Union(parts), (-1.05, -1.05, -0.75), (1.05, 1.05, 0.75), h)
    return clean_mesh(ta.Mesh(v, f, name="flange"))


def test_folded_share_by_hand():
    from torchakvf.mesh.coarse import CoarseMesh, folded_share
    from torchakvf.mesh.surface_map import SurfacePoints

    s = shapes.icosphere(2)
    fine = clean_mesh(ta.Mesh(s.vertices, s.faces))
    n = len(fine.faces)
    on = SurfacePoints(np.arange(n), np.full((n, 3), 1 / 3), np.zeros(n))
    flipped = fine.faces.copy()
    flipped[: n // 2] = flipped[: n // 2, ::-1]            # half the faces point inward
    area = face_areas(fine.vertices, fine.faces)
    for coarse_faces, want in ((fine.faces, 0.0), (flipped, area[: n // 2].sum() / area.sum())):
        coarse = ta.mesh.CleanMesh(fine.vertices, coarse_faces, np.arange(n), n, np.zeros(n, dtype=np.int64), "c",
                                   coarse_faces)
        cm = CoarseMesh(coarse=coarse, fine=fine, vertices_on_coarse=on, faces_on_coarse=on)
        assert folded_share(cm) == pytest.approx(want, abs=1e-12)


def test_a_folded_decimation_is_made_again_with_more_faces():
    """Collapsed to 1,000 faces, the flange's flat caps become fans of long triangles through
    the hubs: a fifth of the surface lies above coarse faces pointing the other way. The coarse
    mesh is made again at 2,000 faces, where it does not fold."""
    from torchakvf.mesh.coarse import FOLDED_SHARE, coarse_mesh_at, folded_share

    flange = _double_flange()
    assert folded_share(coarse_mesh_at(flange, 1000)) > 2 * FOLDED_SHARE
    cm = coarse_mesh(flange, 1000)
    assert cm.faces_asked == 2000 and abs(len(cm.coarse.faces) - 2000) <= 10
    assert folded_share(cm) < 0.01
    # where it does not fold, the face count asked is kept
    assert coarse_mesh(flange, 4000).faces_asked == 4000
