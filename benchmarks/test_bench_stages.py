"""Throughput per pipeline stage over a grid of batch size x mesh size x device.

Run: ``python -m pytest benchmarks/test_bench_stages.py --benchmark-enable`` (CI does not run
benchmarks). CUDA cases skip without a GPU. Compare rows of one run only: the ratio of a
batched case to its one-mesh-at-a-time twin is the figure of interest. Every case also checks
what it timed (a batch of copies of one mesh: every copy gets the first copy's result).
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.mesh.batch import pad_packed
from torchakvf.operators import killing_operator

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(),
                                                               reason="no CUDA device"))]
SIZES = {"small": lambda: shapes.icosphere(3), "medium": lambda: shapes.dumbbell(n_around=48),
         "large": lambda: shapes.three_blobs()}


def _batch(size: str, count: int, device: str) -> ta.MeshBatch:
    s = SIZES[size]()
    return ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces, name=f"{size}{i}") for i in range(count)],
                                    device=device)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", list(SIZES))
@pytest.mark.parametrize("count", [1, 4])
def test_operator_assembly(benchmark, device, size, count):
    batch = _batch(size, count, device)
    system = benchmark.pedantic(lambda: killing_operator(batch, remedy="smooth"), rounds=3, warmup_rounds=1)
    r = system.stiffness.coalesce()
    assert r.shape == (len(batch.edges), len(batch.edges))
    dense_diag = torch.zeros(len(batch.edges), dtype=r.dtype, device=r.device).index_add_(
        0, r.indices()[0], torch.where(r.indices()[0] == r.indices()[1], r.values(), torch.zeros_like(r.values())))
    assert bool((system.mass > 0).all()) and bool((dense_diag > 0).all())
    diff = (r - r.t().coalesce()).coalesce().values().abs().max()
    assert float(diff) <= 1e-12 * float(r.values().abs().max())


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", ["small", "medium"])
@pytest.mark.parametrize("count", [1, 4])
@pytest.mark.parametrize("method", ["lobpcg", "lanczos"])
def test_eigensolve(benchmark, device, size, count, method):
    if method == "lanczos" and device != "cpu":
        pytest.skip("ARPACK runs on the CPU only")
    batch = _batch(size, count, device)
    res = benchmark.pedantic(lambda: ta.akvf(batch, n=32, remedy="smooth", solver=method), rounds=2)
    assert bool(res.converged.all()), res.residuals.max()
    lam = res.eigenvalues
    assert bool((lam[:, 1:] >= lam[:, :-1] - 1e-9).all())
    torch.testing.assert_close(lam, lam[:1].expand_as(lam), rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_untangle(benchmark, device, count):
    fields = ta.akvf(_batch("medium", count, device), n=16, remedy="smooth")
    unt = benchmark.pedantic(lambda: ta.untangle(fields, seed=0), rounds=3)
    a = unt.rotation.double()
    eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device).expand_as(a)
    torch.testing.assert_close(a.transpose(1, 2) @ a, eye, rtol=0, atol=1e-10)
    # Untangling raises the orthomax objective above the raw eigenbasis' (on these copies).
    y = fields.forms.double() * fields.system.mass.double().sqrt()[:, None]
    raw = torch.zeros(count, dtype=y.dtype, device=y.device).index_add_(0, fields.batch.edge_to_mesh, (y ** 4).sum(1))
    assert bool((unt.score > raw).all())
    torch.testing.assert_close(unt.score, unt.score[:1].expand_as(unt.score), rtol=1e-4, atol=0)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_kmeans(benchmark, device, count):
    fields = ta.akvf(_batch("medium", count, device), n=16, remedy="smooth")
    unt = ta.untangle(fields, seed=0)
    x, mask = pad_packed(unt.features.double(), fields.batch.face_ptr)
    km = benchmark.pedantic(lambda: spherical_kmeans(x, mask, 4, restarts=20, seed=0), rounds=3)
    assert int(km.labels[mask].min()) == 0 and int(km.labels[mask].max()) == 3
    assert bool((km.labels[~mask] == -1).all())
    # The cost is Σ (1 - cos) of each row to its center.
    xn = torch.nn.functional.normalize(x, dim=-1)
    cos = (xn * km.centers.gather(1, km.labels.clamp(min=0)[..., None].expand_as(xn))).sum(-1)
    torch.testing.assert_close(((1 - cos) * mask).sum(1), km.cost, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_whole_pipeline(benchmark, device, count):
    batch = _batch("medium", count, device)
    seg = benchmark.pedantic(lambda: ta.segment(batch, k=2, seed=0), rounds=2)
    truth = shapes.dumbbell(n_around=48).part_labels
    for m in seg.meshes:
        # The two blobs, up to which is called 0 (faces on the neck may go either way).
        agree = max(np.mean(m.labels == truth), np.mean(m.labels == 1 - truth))
        assert agree > 0.9, agree
