"""torchakvf.parts.input_descriptors: the batch the descriptors solve on, and the columns on the
input's faces."""
from __future__ import annotations

import numpy as np

from torchakvf import Mesh, MeshBatch, shapes
from torchakvf.interop import face_features
from torchakvf.mesh.clean import face_areas
from torchakvf.mesh.coarse import canonical_numbering
from torchakvf.parts.input_descriptors import descriptor_batch, pack_for_descriptors


def _moved_renumbered(v: np.ndarray, f: np.ndarray, seed: int = 3):
    """(a rotated, translated copy with vertices and faces renumbered, pf: its face i is the
    input's face pf[i])."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    pv, pf = rng.permutation(len(v)), rng.permutation(len(f))
    return Mesh((v @ q.T + np.array([1.0, -2.0, 0.5]))[pv], np.argsort(pv)[f][pf]), pf


def test_a_decimated_mesh_is_decimated_again_canonically_and_the_batch_is_untouched():
    s = shapes.fish()
    batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces)], coarse_faces=2000)
    own = batch.coarse_of(0)
    faces_before = own.coarse.faces.copy()
    d = descriptor_batch(batch)
    c = d.coarse_of(0)
    assert c.canonical and not own.canonical and c.faces_asked == own.faces_asked == 2000
    assert c.fine is own.fine                              # results land on the same input faces
    assert d.meshes[0] is c.coarse and batch.meshes[0] is own.coarse
    np.testing.assert_array_equal(batch.coarse_of(0).coarse.faces, faces_before)
    assert descriptor_batch(d).coarse_of(0) is c          # already canonical: kept


def test_a_mesh_at_full_resolution_is_renumbered_from_its_surface():
    s = shapes.table()                                     # 4,320 faces: not decimated at 4000
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    batch = MeshBatch.from_meshes([Mesh(v, f)], coarse_faces=4000)
    assert batch.coarse_of(0) is None
    m = descriptor_batch(batch).meshes[0]
    order, faces, face_order, _ = canonical_numbering(batch.meshes[0].vertices, batch.meshes[0].faces)
    np.testing.assert_array_equal(m.faces, faces)
    np.testing.assert_array_equal(m.vertices, batch.meshes[0].vertices[order])
    # each renumbered face still names its input face: the same triangle
    tri = lambda verts, fs: np.sort(verts[fs].reshape(len(fs), -1), axis=1)  # noqa: E731
    np.testing.assert_array_equal(tri(m.vertices, m.faces), tri(v, f[m.face_index]))


def test_a_moved_renumbered_copy_solved_as_it_is_gets_the_same_field_columns():
    """The exactly symmetric table, solved undecimated: renumbered from the surface, a moved,
    renumbered copy is solved and untangled in the same order. The columns of the fields' span
    (log_density, coherence) repeat to the solver's tolerance; the untangled ones within the
    stability target, 0.10 (its untangling meets near-ties whose winner the copy's round-off and
    the CPU's kernels decide: 0.016 on one AMD EPYC, within 1e-5 on others; its part columns are not
    checked: the cut reads the copy's coordinates, see docs/descriptors.md)."""
    s = shapes.table()
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces)
    moved, pf = _moved_renumbered(v, f)
    run = lambda mesh: face_features(MeshBatch.from_meshes([mesh], coarse_faces=4000), 8,  # noqa: E731
                                     part_descriptors=False)[0]
    first = run(Mesh(v, f))
    d0 = first.descriptors
    back = np.empty_like(d0)
    back[pf] = run(moved).descriptors
    area = face_areas(v, f)
    area /= area.sum()
    rel = np.sqrt(area @ (back - d0) ** 2) / np.sqrt(area @ d0 ** 2)       # [d], docs/descriptors.md
    span = np.array([n.startswith(("log_density", "coherence")) for n in first.descriptor_names])
    assert span.sum() == 3 and len(span) == 11
    assert rel[span].max() <= 1e-6
    assert rel.max() <= 0.10


def test_pack_for_descriptors_decimates_once_as_descriptor_batch_does():
    from torchakvf.mesh.clean import clean_mesh
    s = shapes.fish()
    clean = clean_mesh(Mesh(s.vertices, s.faces))
    table = clean_mesh(Mesh(shapes.table().vertices, shapes.table().faces))
    packed = pack_for_descriptors([clean, table], 2000)
    again = descriptor_batch(MeshBatch.from_meshes([clean, table], coarse_faces=2000))
    assert packed.coarse_of(0).canonical
    np.testing.assert_array_equal(packed.meshes[0].faces, again.meshes[0].faces)
    np.testing.assert_array_equal(packed.meshes[0].vertices, again.meshes[0].vertices)
    np.testing.assert_array_equal(packed.coarse_of(0).faces_on_coarse.face, again.coarse_of(0).faces_on_coarse.face)
    # the table (4,320 faces) is decimated too at 2000: both paths give the same canonical collapse
    np.testing.assert_array_equal(packed.meshes[1].faces, again.meshes[1].faces)
    assert packed.verts.shape == again.verts.shape


def test_a_canonical_decimation_that_cannot_be_solved_gives_way_to_the_segmentations():
    """Where the solve fails on a mesh's canonical coarse mesh (a SolverError naming it), that
    mesh is solved on the segmentations' decimation instead; its mates keep theirs."""
    import pytest

    from torchakvf.errors import SolverError
    from torchakvf.mesh import clean_mesh
    from torchakvf.parts.input_descriptors import solve_descriptor_batch

    meshes = [clean_mesh(Mesh(s.vertices, s.faces)) for s in (shapes.quadruped(0.06), shapes.fish(0.05))]
    batch = pack_for_descriptors(meshes, 1500)
    assert all(batch.coarse_of(b).canonical for b in range(2))
    seen = []

    def solve(mb):
        seen.append([mb.coarse_of(b).canonical for b in range(2)])
        if mb.coarse_of(1).canonical:
            exc = SolverError("fish: no shift made R - σS1 positive definite")
            exc.failed_meshes = [1]
            raise exc
        return mb

    out = solve_descriptor_batch(batch, solve)
    assert seen == [[True, True], [True, False]]
    ordinary = MeshBatch.from_meshes([meshes[1]], coarse_faces=1500).coarse_of(0).coarse
    assert np.array_equal(out.meshes[1].vertices, ordinary.vertices) and np.array_equal(out.meshes[0].vertices,
                                                                                        batch.meshes[0].vertices)

    def fails_elsewhere(mb):
        raise SolverError("no mesh named")

    with pytest.raises(SolverError, match="no mesh named"):
        solve_descriptor_batch(batch, fails_elsewhere)


def test_the_boundary_columns_are_the_coarse_faces_cues_and_the_model_of_each_row():
    """At the default counts the descriptors end with the crease cues of the coarse face under
    each input face and the package's boundary probability of the row's 41 columns and cues;
    other counts have neither."""
    from torchakvf.parts.boundary_cues import CUE_NAMES, crease_cues
    from torchakvf.parts.boundary_probability import boundary_probability
    s = shapes.fish()
    batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces)], coarse_faces=2000)
    ff = face_features(batch, 32)[0]
    assert ff.descriptors.shape == (len(s.faces), 48)
    assert ff.descriptor_names[40:] == ["cut_share_0.06"] + list(CUE_NAMES) + ["boundary_probability"]
    d = descriptor_batch(batch)
    packed = d.meshes[0]
    cues = d.to_input_faces(0, crease_cues(packed.vertices, packed.faces))
    np.testing.assert_allclose(ff.descriptors[:, 41:47], cues, atol=1e-12)
    p = boundary_probability(ff.descriptors[:, :41], ff.descriptors[:, 41:47])
    np.testing.assert_array_equal(ff.descriptors[:, 47], p)
    assert 0.0 < p.min() and p.max() < 1.0 and p.std() > 0.01
    assert "boundary_probability" not in face_features(batch, 16)[0].descriptor_names
