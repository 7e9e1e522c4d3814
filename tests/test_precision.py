"""float32 iterations of untangling and k-means, checked against float64 (the defaults use
float32 for the large products only; every choice between results is made in float64)."""
from __future__ import annotations

import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.mesh.batch import pad_packed


@pytest.fixture(scope="module")
def fields():
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in
              (("three_blobs", shapes.three_blobs()), ("bent", shapes.bend(shapes.dumbbell(), 0.6)))]
    return ta.akvf(ta.MeshBatch.from_meshes(meshes), n=20, remedy="smooth")


def test_untangle_float32_iterations_match_float64(fields):
    a = ta.untangle(fields, n=16, seed=0, iteration_dtype=torch.float64)
    b = ta.untangle(fields, n=16, seed=0, iteration_dtype=torch.float32)
    assert torch.allclose(a.score, b.score, rtol=1e-6)
    # The same rotation: every float64 field has a float32 twin (|cos| ~ 1).
    for m in range(len(fields.batch)):
        cos = (a.rotation[m].T @ b.rotation[m]).abs().max(dim=1).values
        assert cos.min() > 1 - 1e-6, cos.min()
    assert (a.features - b.features).abs().max() < 1e-4 * a.features.abs().max()
    assert a.rotation.dtype == torch.float64


def test_kmeans_float32_iterations_give_float64_labels(fields):
    unt = ta.untangle(fields, n=16, seed=0)
    x, mask = pad_packed(unt.features.double(), fields.batch.face_ptr)
    for k in (3, 9):
        a = spherical_kmeans(x, mask, k, seed=0, iteration_dtype=torch.float64)
        b = spherical_kmeans(x, mask, k, seed=0, iteration_dtype=torch.float32)
        agree = (a.labels == b.labels)[mask].double().mean().item()
        assert agree > 0.999, (k, agree)
        assert torch.allclose(a.cost, b.cost, rtol=1e-6)
        assert b.centers.dtype == torch.float64
