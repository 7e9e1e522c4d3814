"""Per-face AKVF descriptors: shape, documented ranges, and invariance to the order and sign of
the fields, rigid motions, vertex renumbering and the solver's seed."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from torchakvf import Mesh, MeshBatch, akvf, load_mesh, shapes
from torchakvf.errors import ParameterError
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.fields.descriptors import (
    BASE_COLUMNS,
    CONTRAST_RADII,
    DEFAULT_COUNTS,
    FaceDiffusion,
    counts_for,
    descriptor_block,
    descriptor_names,
    face_descriptors,
    span_coherence,
)
from torchakvf.fields.untangle import untangle
from torchakvf.shapes import dumbbell, three_blobs

#: Columns that depend on the raw fields' span only (never on the untangling).
SPAN_ONLY = ("log_density", "coherence")


def _mesh(shape, stretch=(1.0, 1.0, 1.0)) -> Mesh:
    return Mesh(np.asarray(shape.vertices) * np.asarray(stretch), shape.faces)


def _descriptors(mesh: Mesh, seed: int = 0, counts=(8, 16)) -> np.ndarray:
    """[F_input, d] descriptors on the mesh's input faces; ``seed`` the solver's (the
    descriptors untangle with their own)."""
    batch = MeshBatch.from_meshes([mesh])
    # the invariance tolerances below were measured on the remedied operator; these clean
    # shapes get the paper's under the default ("auto"), not measured here
    fields = akvf(batch, n=max(counts), seed=seed, remedy="smooth")
    return batch.meshes[0].to_input_faces(face_descriptors(fields, counts)[0].numpy())


def _moved(mesh: Mesh, seed: int = 3) -> Mesh:
    """``mesh`` rotated, translated and scaled (descriptors live in the unit-area frame)."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return Mesh(2.5 * np.asarray(mesh.vertices) @ q.T + np.array([1.0, -2.0, 0.5]), mesh.faces)


def _renumbered(mesh: Mesh, seed: int = 4) -> tuple[Mesh, np.ndarray]:
    """(``mesh`` with vertices and faces shuffled, face order: new face i is old face order[i])."""
    rng = np.random.default_rng(seed)
    pv = rng.permutation(len(mesh.vertices))
    pf = rng.permutation(len(mesh.faces))
    return Mesh(np.asarray(mesh.vertices)[pv], np.argsort(pv)[np.asarray(mesh.faces)][pf]), pf


def _assert_same(other: np.ndarray, d0: np.ndarray, counts, atol: float) -> None:
    """Span columns to the eigensolver's tolerance; untangling columns to ``atol`` (the
    untangling stops on a relative objective change of 1e-6, not at the exact optimum)."""
    span = _span_columns(counts)
    np.testing.assert_allclose(other[:, span], d0[:, span], atol=1e-5)
    np.testing.assert_allclose(other, d0, atol=atol)


def _span_columns(counts) -> np.ndarray:
    names = descriptor_names(counts)
    return np.array([any(n.startswith(c) for c in SPAN_ONLY) for n in names])


@pytest.fixture(scope="module")
def blobs() -> Mesh:
    # stretched across the axis: no continuous symmetry (its untangling still has competing
    # optima, objectives within 1e-5 of each other, so the invariances are tested on a table)
    return _mesh(three_blobs(n_around=30), (1.0, 0.8, 1.0))


def test_names_and_shape(blobs):
    d = _descriptors(blobs, counts=(8, 16))
    names = descriptor_names((8, 16))
    assert d.shape == (len(blobs.faces), len(names))
    assert len(names) == 2 * (len(BASE_COLUMNS) + 2 * len(CONTRAST_RADII))
    assert len(set(names)) == len(names)
    assert len(descriptor_names()) == len(DEFAULT_COUNTS) * (len(BASE_COLUMNS) + 2 * len(CONTRAST_RADII))
    assert np.isfinite(d).all()


def test_documented_ranges(blobs):
    counts = (8, 16)
    d = _descriptors(blobs, counts=counts)
    col = {n: d[:, i] for i, n in enumerate(descriptor_names(counts))}
    eps = 1e-9
    for n in counts:
        assert (col[f"share1@{n}"] >= 1.0 / n - eps).all() and (col[f"share1@{n}"] <= 1 + eps).all()
        assert (col[f"share2@{n}"] >= -eps).all() and (col[f"share2@{n}"] <= 0.5 + eps).all()
        assert (col[f"share3@{n}"] >= -eps).all() and (col[f"share3@{n}"] <= 1 / 3 + eps).all()
        assert (col[f"share2@{n}"] <= col[f"share1@{n}"] + eps).all()
        assert (col[f"share3@{n}"] <= col[f"share2@{n}"] + eps).all()
        assert (col[f"entropy@{n}"] >= -eps).all() and (col[f"entropy@{n}"] <= 1 + eps).all()
        assert (col[f"energy@{n}"] >= 0).all()
        assert (col[f"part_area@{n}"] > 0).all() and (col[f"part_area@{n}"] <= 1 + eps).all()
        for r in CONTRAST_RADII:
            for c in (f"contrast_{r:g}@{n}", f"coherence_{r:g}@{n}"):
                assert (col[c] >= 0).all() and (col[c] <= 1).all()


def test_order_and_sign_of_fields_do_not_matter(blobs):
    batch = MeshBatch.from_meshes([blobs])
    fields = akvf(batch, n=8, seed=0)
    unt = untangle(fields, 8, seed=0)
    phi = unt.mesh_features(0).numpy()
    energies = unt.energies[0].numpy()
    mesh = batch.meshes[0]
    area = 0.5 * np.linalg.norm(np.cross(*(mesh.vertices[mesh.faces[:, k]] - mesh.vertices[mesh.faces[:, 0]]
                                          for k in (1, 2))), axis=1)
    diffusion = FaceDiffusion(mesh.vertices, mesh.faces)
    perm = np.random.default_rng(0).permutation(8)
    a = descriptor_block(phi, energies, area, diffusion)
    b = descriptor_block(phi[:, perm], energies[perm], area, diffusion)
    np.testing.assert_allclose(a, b, atol=1e-12)
    # any orthogonal mix of the fields (not just a signed permutation) leaves the span columns
    vectors = fields.face_vectors.numpy()
    q, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((8, 8)))
    np.testing.assert_allclose(span_coherence(vectors, diffusion),
                               span_coherence(np.einsum("fnc,nm->fmc", vectors, q), diffusion), atol=1e-10)


def test_rigid_motion_renumbering_and_seed():
    """On a shape whose untangling optimum is well separated: the built-in table at 6 fields
    (every restart ends on one objective to 1e-14 but one far below; λ·area 39 -> 65 after the
    6th field). On the stretched blobs the restarts end on competing optima within 1e-5 of each
    other, which round-off on another CPU picks among: columns 0.3 apart (seen with SSE MKL)."""
    table = _mesh(shapes.table())
    counts = (6,)
    d0 = _descriptors(table, counts=counts)
    # the fields to the eigensolve's residual (1e-6) over the gap after them (~1e-6 x λ / gap),
    # the rotation to its stopping test: 1e-8 seen, 1e-5 asked for
    _assert_same(_descriptors(_moved(table), counts=counts), d0, counts, atol=1e-5)
    shuffled, order = _renumbered(table)
    d_shuffled = np.empty_like(d0)
    d_shuffled[order] = _descriptors(shuffled, counts=counts)
    _assert_same(d_shuffled, d0, counts, atol=1e-5)
    _assert_same(_descriptors(table, seed=1, counts=counts), d0, counts, atol=1e-5)


def test_span_columns_repeat_where_the_optimum_is_not_unique():
    # an exactly rotation-symmetric shape: any rotation of a sphere's fields about the axis is
    # as good an untangling, so only the span columns must repeat across seeds
    mesh = _mesh(dumbbell(n_around=30))
    counts = (8, 16)
    span = _span_columns(counts)
    d0, d1 = _descriptors(mesh, seed=0, counts=counts), _descriptors(mesh, seed=1, counts=counts)
    np.testing.assert_allclose(d1[:, span], d0[:, span], atol=1e-6)


@pytest.mark.skipif(default_psb_root() is None, reason="PSB data not present")
def test_psb_mesh_invariance():
    fine = load_mesh(default_psb_root() / "meshes" / "1.off.gz")
    packed = MeshBatch.from_meshes([fine], coarse_faces=1500).meshes[0]
    mesh = Mesh(packed.vertices, packed.faces)
    counts = (8, 16)
    d0 = _descriptors(mesh, counts=counts)
    for other in (_descriptors(_moved(mesh), counts=counts), _descriptors(mesh, seed=1, counts=counts)):
        _assert_same(other, d0, counts, atol=2e-2)


def test_bad_counts_and_missing_diffusion(blobs):
    fields = akvf(MeshBatch.from_meshes([blobs]), n=8, seed=0)
    with pytest.raises(ParameterError, match="field counts"):
        face_descriptors(fields, (8, 16))
    with pytest.raises(ParameterError, match="field counts"):
        face_descriptors(fields, 1)
    with pytest.raises(ParameterError, match="FaceDiffusion"):
        descriptor_block(np.ones((4, 3)), np.zeros(3), np.ones(4), None)
    assert face_descriptors(fields, 8, radii=())[0].shape[1] == len(BASE_COLUMNS)


def test_counts_for_a_field_count(blobs):
    assert counts_for(32) == DEFAULT_COUNTS and counts_for(20) == (8, 16, 20)
    assert counts_for(8) == (8,) and counts_for(4) == (4,) and counts_for(1) == ()
    fields = akvf(MeshBatch.from_meshes([blobs]), n=8, seed=0)
    assert face_descriptors(fields, counts_for(1))[0].shape == (len(blobs.faces), 0)


def test_device_and_dtype_follow_the_fields(blobs):
    fields = akvf(MeshBatch.from_meshes([blobs]), n=8, seed=0)
    d = face_descriptors(fields, 8)[0]
    assert d.dtype == fields.forms.dtype and d.device == fields.forms.device
    assert d.dtype == torch.float64
