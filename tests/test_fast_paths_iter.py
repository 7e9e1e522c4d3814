"""The iterations' one-mesh CPU fast paths give the general (batched, any-device) paths'
answers bitwise (issue 13): Horst's iteration of the untangling and Lloyd's of spherical
k-means, alone and inside their callers, with restarts that stop at different iterations."""
from __future__ import annotations

import importlib

import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans

untangle_mod = importlib.import_module("torchakvf.fields.untangle")
horst_mod = importlib.import_module("torchakvf.fields.horst")
kmeans_mod = importlib.import_module("torchakvf.cluster.spherical_kmeans")


def _horst_problem(n: int, e: int, r: int, seed: int):
    """Scaled forms [1, e, n] with some structure (a block of rows heavier on half the fields)
    and r starts: the identity and r - 1 random rotations."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.randn(1, e, n, generator=gen, dtype=torch.float64)
    y[0, :e // 3, :n // 2] *= 4
    rots = untangle_mod.random_rotations(r - 1, n, gen)
    a = torch.cat([torch.eye(n, dtype=torch.float64)[None], rots])[None]
    return y, a


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-6)])
@pytest.mark.parametrize("n,e,r", [(6, 300, 4), (12, 900, 2), (4, 120, 1)])
def test_horst_one_mesh_equals_the_batched_path(n, e, r, dtype, tol):
    y, a = _horst_problem(n, e, r, seed=n + r)
    fast_a, fast_iters = horst_mod.horst_one_mesh(y, a, tol, 500, dtype)
    ref_a, ref_iters = horst_mod.horst_batched(y, a, tol, 500, dtype)
    assert torch.equal(fast_a, ref_a)
    assert torch.equal(fast_iters, ref_iters)
    assert fast_iters.dtype == ref_iters.dtype and fast_a.shape == ref_a.shape
    if r > 1:
        assert len(set(ref_iters[0].tolist())) > 1    # restarts stopped at different steps
    # the iteration cap, and the dispatch of _horst for one CPU mesh
    capped = horst_mod.horst(y, a, tol, 3, dtype)
    for got, ref in zip(capped, horst_mod.horst_batched(y, a, tol, 3, dtype)):
        assert torch.equal(got, ref)
    assert (capped[1] == 3).all()


@pytest.fixture(scope="module")
def blob_fields():
    s = shapes.three_blobs()
    return ta.akvf(ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)]), n=14, remedy="smooth")


def test_orthomax_rotations_equal_the_batched_path(blob_fields, monkeypatch):
    fast = untangle_mod.orthomax_rotations(blob_fields, {0: 10}, restarts=2, seed=1)
    monkeypatch.setattr(untangle_mod, "horst", horst_mod.horst_batched)
    ref = untangle_mod.orthomax_rotations(blob_fields, {0: 10}, restarts=2, seed=1)
    assert torch.equal(fast[0].rotation, ref[0].rotation)
    assert torch.equal(fast[0].restart_scores, ref[0].restart_scores)
    assert (fast[0].score, fast[0].iterations) == (ref[0].score, ref[0].iterations)


def _kmeans_problem(n_rows: int, d: int, k: int, r: int, seed: int, duplicate: bool = False):
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(1, n_rows, d, generator=gen, dtype=torch.float64)
    x[0, :n_rows // 2] += 2 * torch.randn(d, generator=gen, dtype=torch.float64)
    x = torch.nn.functional.normalize(x, dim=-1)
    w = torch.rand(1, n_rows, generator=gen, dtype=torch.float64)
    seeds = x[:, torch.randperm(n_rows, generator=gen)[:r * k]].reshape(1, r, k, d).clone()
    if duplicate:
        # two equal centers: ties in every similarity row, and one of them is emptied
        seeds[:, :, 1] = seeds[:, :, 0]
    return x, w, seeds


@pytest.mark.parametrize("dtype,max_iter", [(torch.float32, 15), (torch.float32, 100), (torch.float64, 100)])
@pytest.mark.parametrize("n_rows,d,k,r,duplicate", [(300, 6, 7, 5, False), (400, 8, 12, 3, True),
                                                    (200, 5, 3, 1, False), (150, 4, 1, 2, False)])
def test_lloyd_one_mesh_equals_the_batched_path(n_rows, d, k, r, duplicate, dtype, max_iter):
    x, w, seeds = _kmeans_problem(n_rows, d, k, r, seed=k + r, duplicate=duplicate)
    fast = kmeans_mod._lloyd_one_mesh(x, w, seeds, max_iter, dtype)
    ref = kmeans_mod._lloyd_batched(x, w, seeds, max_iter, dtype)
    for got, want in zip(fast, ref):
        assert got.dtype == want.dtype and torch.equal(got, want)
    # the dispatch: one CPU mesh with every center present
    for got, want in zip(kmeans_mod._lloyd(x, w, seeds, max_iter, dtype, torch.ones(1, k, dtype=torch.bool)), ref):
        assert torch.equal(got, want)


def test_lloyd_one_mesh_keeps_seed_layout_out_of_the_answer():
    """Seeds handed over as a strided view (as spherical_kmeans slices them) give the bits of
    contiguous seeds."""
    x, w, seeds = _kmeans_problem(300, 6, 5, 3, seed=7)
    wide = torch.zeros(1, 3, 9, 6, dtype=torch.float64)
    wide[:, :, :5] = seeds
    fast = kmeans_mod._lloyd_one_mesh(x, w, wide[:, :, :5], 100, torch.float32)
    ref = kmeans_mod._lloyd_batched(x, w, seeds, 100, torch.float32)
    for got, want in zip(fast, ref):
        assert torch.equal(got, want)


def test_spherical_kmeans_equals_the_batched_path(monkeypatch):
    """Two meshes of other k's (each mesh alone through the fast path on CPU) against the
    general path for each mesh."""
    gen = torch.Generator().manual_seed(11)
    x = torch.randn(2, 250, 6, generator=gen, dtype=torch.float64)
    mask = torch.ones(2, 250, dtype=torch.bool)
    mask[1, 200:] = False
    w = torch.rand(2, 250, generator=gen, dtype=torch.float64)
    fast = spherical_kmeans(x, mask, [4, 9], restarts=5, seed=2, weights=w, max_iter=15)
    monkeypatch.setattr(kmeans_mod, "_lloyd", kmeans_mod._lloyd_batched)
    ref = spherical_kmeans(x, mask, [4, 9], restarts=5, seed=2, weights=w, max_iter=15)
    for name in ("labels", "centers", "cost", "iterations", "restart_costs"):
        assert torch.equal(getattr(fast, name), getattr(ref, name)), name
