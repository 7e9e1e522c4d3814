"""Canonical signs of AKVFs: the vorticity moment against a face-by-face computation, and the
same signed fields from another eigensolver start or a copy of the mesh with flipped fields."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from torchakvf import Mesh, MeshBatch, akvf
from torchakvf.fields.canonical import SIGN_MOMENT_FLOOR, canonical_signs, vorticity_moments
from torchakvf.shapes import three_blobs


@pytest.fixture(scope="module")
def mesh() -> Mesh:
    s = three_blobs(n_around=20)
    # stretched and bent: no symmetry, so no field's moment is zero by symmetry (a mirror or a
    # rotation of the surface that reverses a field makes one or both vanish)
    v = np.asarray(s.vertices) * np.array([1.0, 0.8, 1.0])
    u = v / np.abs(v).max(axis=0)
    bend = np.stack([u[:, 1] * u[:, 2], u[:, 0] ** 2, u[:, 0] * u[:, 1] + u[:, 2] ** 2], axis=1)
    return Mesh(v + 0.08 * np.abs(v).max(axis=0) * bend, s.faces)


def _moments_by_hand(fields) -> np.ndarray:
    """[n] Σ a ω³ / (Σ a ω²)^1.5 + Σ a r³ / (Σ a r²)^1.5 with each face's circulation summed
    over its oriented edges looked up by vertex pair (no face_edges / face_edge_sign) and r the
    face vector's component along the face centroid minus the area centroid."""
    batch = fields.batch
    edges = batch.edges.numpy()
    index = {(int(i), int(j)): e for e, (i, j) in enumerate(edges)}
    forms = fields.forms.numpy()
    v = batch.verts.numpy()
    out_circ, out_area = [], []
    for face in batch.faces.numpy():
        c = np.zeros(forms.shape[1])
        for k in range(3):
            a, b = int(face[k]), int(face[(k + 1) % 3])
            c += forms[index[(a, b)]] if (a, b) in index else -forms[index[(b, a)]]
        out_circ.append(c)
        out_area.append(0.5 * np.linalg.norm(np.cross(v[face[1]] - v[face[0]], v[face[2]] - v[face[0]])))
    circ, area = np.array(out_circ), np.array(out_area)
    area = area / area.sum()
    omega = circ / area[:, None]
    centers = v[batch.faces.numpy()].mean(axis=1)
    r = np.einsum("fnc,fc->fn", fields.face_vectors.numpy(), centers - area @ centers)
    return (area @ omega ** 3) / (area @ omega ** 2) ** 1.5 + (area @ r ** 3) / (area @ r ** 2) ** 1.5


def test_vorticity_moments_by_hand(mesh):
    fields = akvf(MeshBatch.from_meshes([mesh]), n=6, seed=0)
    np.testing.assert_allclose(vorticity_moments(fields)[0].numpy(), _moments_by_hand(fields), rtol=1e-9,
                               atol=1e-12)


def test_signs_are_the_surfaces(mesh):
    batch = MeshBatch.from_meshes([mesh])
    a = canonical_signs(akvf(batch, n=6, seed=0))
    moments = vorticity_moments(a)[0]
    assert (moments > 1e-3).all(), moments
    # another start vector: the fields come back with other signs, and leave with the same
    b0 = akvf(batch, n=6, seed=5)
    b = canonical_signs(b0)
    np.testing.assert_allclose(b.face_vectors.numpy(), a.face_vectors.numpy(), atol=1e-5)
    # flipping fields by hand changes nothing; norms and eigenvalues are untouched
    flip = torch.tensor([-1.0, 1.0, -1.0, -1.0, 1.0, 1.0], dtype=b0.forms.dtype)
    c = canonical_signs(dataclasses.replace(b0, forms=b0.forms * flip, face_vectors=b0.face_vectors * flip[:, None]))
    np.testing.assert_array_equal(c.forms.numpy(), b.forms.numpy())
    np.testing.assert_array_equal(b.face_vectors.norm(dim=-1).numpy(), b0.face_vectors.norm(dim=-1).numpy())
    assert b.eigenvalues is b0.eigenvalues
    # applying it twice is applying it once
    np.testing.assert_array_equal(canonical_signs(b).forms.numpy(), b.forms.numpy())


def test_a_field_a_symmetry_makes_odd_keeps_the_solvers_sign():
    # the unbent blobs are mirror symmetric: some fields' moments are round-off, and those
    # fields are left as solved instead of flipped on round-off
    s = three_blobs(n_around=20)
    fields = akvf(MeshBatch.from_meshes([Mesh(np.asarray(s.vertices) * np.array([1.0, 0.8, 1.0]), s.faces)]),
                  n=6, seed=0)
    moments = vorticity_moments(fields)[0]
    odd = moments.abs() < SIGN_MOMENT_FLOOR
    assert odd.any() and (~odd).any(), moments
    out = canonical_signs(fields)
    np.testing.assert_array_equal(out.forms[:, odd].numpy(), fields.forms[:, odd].numpy())
    assert (vorticity_moments(out)[0][~odd] > 0).all()
