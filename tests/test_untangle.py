"""Untangling (:mod:`torchakvf.fields.untangle`): a mesh's rotation independent of its batch, the
one-mesh path against the batched one, the same answer with either gradient."""
from __future__ import annotations

import importlib

import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.restarts import best_restart


untangle_mod = importlib.import_module("torchakvf.fields.untangle")


@pytest.fixture(scope="module")
def fields():
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in
              (("blobs", shapes.three_blobs(n_around=20)), ("dumbbell", shapes.BUILTIN_SHAPES["dumbbell"]()))]
    return ta.akvf(ta.MeshBatch.from_meshes(meshes), n=24, remedy="smooth")


def test_rotations_of_a_subset_are_the_batch_untangling_bits(fields):
    """orthomax_rotations for one mesh gives the bits untangle gives it in the whole batch
    (each mesh at its own n), and untangled_from_rotations rebuilds untangle's arrays exactly."""
    ns = [16, 18]
    whole = ta.untangle(fields, n=ns, seed=3, restarts=3)
    rots = {}
    for b in (1, 0):
        rots.update(untangle_mod.orthomax_rotations(fields, {b: ns[b]}, seed=3, restarts=3))
    for b in range(2):
        assert torch.equal(rots[b].rotation, whole.rotation[b, :ns[b], :ns[b]].double())
        assert rots[b].score == float(whole.score[b])
        assert rots[b].restart_scores.shape == (4,)
        assert rots[b].score == float(rots[b].restart_scores[best_restart(rots[b].restart_scores[None], largest=True)[0]])
        # the mesh's own edges alone (no padding rows of the batch): the same bits
        e0, e1 = int(fields.batch.edge_ptr[b]), int(fields.batch.edge_ptr[b + 1])
        y = fields.forms[e0:e1, :ns[b]].double() * fields.system.mass[e0:e1].double().sqrt()[:, None]
        own = untangle_mod.orthomax(y[None], 3, 3, 1e-6, 500, torch.float32)
        assert torch.equal(own[0][0], rots[b].rotation)
    again = untangle_mod.untangled_from_rotations(fields, [rots[0], rots[1]])
    for name in ("rotation", "forms", "face_vectors", "features", "energies", "score", "iterations"):
        assert torch.equal(getattr(again, name), getattr(whole, name)), name
    assert again.n_fields == ns


horst_mod = importlib.import_module("torchakvf.fields.horst")


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


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_untangle_is_the_same_with_either_gradient(monkeypatch, dtype):
    """The moments only replace the float64 steps' products (after the float32 phase, or all
    of them with iteration_dtype=float64): the same iterations, rotations and objective to
    round-off."""
    s = shapes.three_blobs()
    fields = ta.akvf(ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)]), n=12)
    monkeypatch.setattr(untangle_mod, "fourth_moments_pay", lambda e, n, steps: True)
    got = untangle_mod.untangle(fields, restarts=3, seed=2, iteration_dtype=dtype)
    monkeypatch.setattr(untangle_mod, "fourth_moments_pay", lambda e, n, steps: False)
    want = untangle_mod.untangle(fields, restarts=3, seed=2, iteration_dtype=dtype)
    assert torch.equal(got.iterations, want.iterations)
    assert float((got.rotation - want.rotation).abs().max()) < 1e-8
    assert float((got.score - want.score).abs().max()) <= 1e-10 * float(want.score.abs().max())
