"""Throughput per pipeline stage over a grid of batch size x mesh size x device.

Run: ``python -m pytest benchmarks/test_bench_stages.py --benchmark-enable`` (CI does not run
benchmarks). CUDA cases skip without a GPU. Compare rows of one run only: the ratio of a
batched case to its one-mesh-at-a-time twin is the figure of interest.
"""
from __future__ import annotations

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
    benchmark.pedantic(lambda: killing_operator(batch, remedy="smooth"), rounds=3, warmup_rounds=1)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", ["small", "medium"])
@pytest.mark.parametrize("count", [1, 4])
@pytest.mark.parametrize("method", ["lobpcg", "lanczos"])
def test_eigensolve(benchmark, device, size, count, method):
    if method == "lanczos" and device != "cpu":
        pytest.skip("ARPACK runs on the CPU only")
    batch = _batch(size, count, device)
    benchmark.pedantic(lambda: ta.akvf(batch, n=32, remedy="smooth", solver=method), rounds=2)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_untangle(benchmark, device, count):
    fields = ta.akvf(_batch("medium", count, device), n=16, remedy="smooth")
    benchmark.pedantic(lambda: ta.untangle(fields, seed=0), rounds=3)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_kmeans(benchmark, device, count):
    fields = ta.akvf(_batch("medium", count, device), n=16, remedy="smooth")
    unt = ta.untangle(fields, seed=0)
    x, mask = pad_packed(unt.features.double(), fields.batch.face_ptr)
    benchmark.pedantic(lambda: spherical_kmeans(x, mask, 4, restarts=20, seed=0), rounds=3)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("count", [1, 4])
def test_whole_pipeline(benchmark, device, count):
    batch = _batch("medium", count, device)
    benchmark.pedantic(lambda: ta.segment(batch, k=2, seed=0), rounds=2)
