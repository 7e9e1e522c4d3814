"""On CPU a batch's AKVFs are solved one mesh at a time (issue 13: batching that never loses),
and untangled fields are made per mesh on demand: the pieces must add up to what the
whole-batch computation gives."""
import warnings

import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import ConvergenceWarning
from torchakvf.operators import killing_operator


@pytest.fixture(scope="module")
def meshes():
    return [ta.Mesh(s.vertices, s.faces, name=s.name)
            for s in (shapes.dumbbell(), shapes.hemisphere(), shapes.three_blobs(n_around=16))]


def test_mesh_of_a_batch_is_the_batch_of_that_mesh(meshes):
    batch = ta.MeshBatch.from_meshes(meshes)
    for b, m in enumerate(meshes):
        one, ref = batch.mesh(b), ta.MeshBatch.from_meshes([m])
        for name in ("verts", "faces", "edges", "face_edges", "face_edge_sign", "vert_ptr", "face_ptr", "edge_ptr"):
            assert torch.equal(getattr(one, name), getattr(ref, name)), name
        assert one.meshes[0] is batch.meshes[b]


def test_concatenated_systems_are_the_batch_system(meshes):
    """R, S1 and the geometry of the meshes assembled one at a time, concatenated, against the
    whole batch assembled at once: the same sparsity, entries equal up to the round-off of
    summing a few terms in another order (relative 1e-12 of each mesh's largest entry)."""
    batch = ta.MeshBatch.from_meshes(meshes)
    whole = killing_operator(batch)
    parts = ta.operators.KillingSystem.concatenate(
        [killing_operator(batch.mesh(b)) for b in range(len(batch))], batch.edge_ptr)
    assert parts.stiffness.is_coalesced()
    assert torch.equal(parts.stiffness.indices(), whole.stiffness.indices())
    scale = whole.stiffness.values().abs().max()
    torch.testing.assert_close(parts.stiffness.values(), whole.stiffness.values(), rtol=0, atol=1e-12 * scale)
    torch.testing.assert_close(parts.mass, whole.mass, rtol=1e-13, atol=0)
    torch.testing.assert_close(parts.star1_raw, whole.star1_raw, rtol=1e-13, atol=1e-15)
    for name in ("points", "scale", "area", "face_area", "normal", "cot", "angle", "grad_bary"):
        torch.testing.assert_close(getattr(parts.geometry, name), getattr(whole.geometry, name),
                                   rtol=1e-12, atol=1e-12, msg=name)


def test_cpu_batch_is_each_mesh_alone_and_one_system(meshes):
    batch = ta.MeshBatch.from_meshes(meshes)
    res = ta.akvf(batch, n=12)
    assert res.batch is batch and res.system.n_meshes == len(meshes)
    assert torch.equal(res.system.edge_ptr, batch.edge_ptr)
    for b, m in enumerate(meshes):
        one = ta.akvf(m, n=12)
        assert torch.equal(res.eigenvalues[b], one.eigenvalues[0])
        assert torch.equal(res.mesh_forms(b), one.forms)
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        assert torch.equal(res.face_vectors[f0:f1], one.face_vectors)
        assert torch.equal(res.residuals[b], one.residuals[0])
    # the residuals stored are those of the concatenated system: R w - λ S1 w cancels terms of
    # size |λ| (up to ~1e2 here), so recomputing it moves it by round-off of ~1e-16 x 1e2 x
    # the rows' sums; 1e-10 is far below the solve's tol (1e-6) and far above that
    from torchakvf.solvers.lobpcg import relative_residuals
    again = relative_residuals(res.system, res.forms, res.eigenvalues)
    torch.testing.assert_close(again, res.residuals, rtol=0, atol=1e-10)


def test_one_warning_names_every_unconverged_mesh(meshes):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = ta.akvf(ta.MeshBatch.from_meshes(meshes[:2]), n=8, tol=1e-30)
    conv = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    assert len(conv) == 1
    assert not bool(res.converged.any())
    for m in meshes[:2]:
        assert m.name in str(conv[0].message)
    assert conv[0].filename == __file__       # reported at the caller of akvf


def test_untangled_fields_made_per_mesh_add_up_to_the_packed_arrays(meshes):
    fields = ta.akvf(ta.MeshBatch.from_meshes(meshes), n=12)
    ns = [8, 12, 10]
    unt = ta.untangle(fields, n=ns, seed=0, restarts=2)
    batch = fields.batch
    assert unt.features.shape == (int(batch.face_ptr[-1]), 12)
    assert unt.face_vectors.shape == (int(batch.face_ptr[-1]), 12, 3)
    assert unt.forms.shape == (int(batch.edge_ptr[-1]), 12)
    for b, n in enumerate(ns):
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        e0, e1 = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        assert torch.equal(unt.features[f0:f1, :n], unt.mesh_features(b))
        assert not unt.features[f0:f1, n:].any() and not unt.face_vectors[f0:f1, n:].any()
        assert torch.equal(unt.face_vectors[f0:f1, :n], unt.mesh_face_vectors(b))
        assert torch.equal(unt.forms[e0:e1, :n], unt.mesh_forms(b))
        a = unt.rotation[b, :n, :n].double()
        # the definitions: raw fields rotated, features their norms, forms S1-orthonormal
        torch.testing.assert_close(unt.mesh_forms(b), fields.mesh_forms(b)[:, :n] @ a)
        torch.testing.assert_close(unt.mesh_features(b), unt.mesh_face_vectors(b).norm(dim=-1))
        gram = unt.mesh_forms(b).T @ (fields.system.mass[e0:e1, None] * unt.mesh_forms(b))
        torch.testing.assert_close(gram, torch.eye(n, dtype=gram.dtype), rtol=0, atol=1e-8)
