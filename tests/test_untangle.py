"""Untangling (:mod:`torchakvf.fields.untangle`): a mesh's rotation independent of its batch, the
one-mesh path against the batched one, the same answer with either gradient, and float32
iterations ending on a float64 optimum."""
from __future__ import annotations

import importlib

import pytest
import torch
from helpers.roundoff import EPS64, horst_roundoff

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.mesh.batch import pad_packed
from torchakvf.restarts import best_restart

untangle_mod = importlib.import_module("torchakvf.fields.untangle")


def test_rotations_of_a_subset_are_the_batch_untangling_bits(fields):
    """orthomax_rotations for one mesh gives the bits untangle gives it in the whole batch
    (each mesh at its own n), and untangled_from_rotations rebuilds untangle's arrays exactly.
    Bitwise by construction: on the CPU each mesh is untangled alone, on its own rows, so both
    sides make the same calls on the same shapes."""
    ns = [16, 18]
    whole = ta.untangle(fields, n=ns, seed=3, restarts=3)
    rots = {}
    for b in (1, 0):
        rots.update(untangle_mod.orthomax_rotations(fields, {b: ns[b]}, seed=3, restarts=3))
    for b in range(2):
        assert torch.equal(rots[b].rotation, whole.rotation[b, :ns[b], :ns[b]].double())
        assert rots[b].score == float(whole.score[b])
        assert rots[b].restart_scores.shape == (4,)
        best = best_restart(rots[b].restart_scores[None], largest=True)[0]
        assert rots[b].score == float(rots[b].restart_scores[best])
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


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_orthomax_rotations_equal_the_batched_path(blob_fields, monkeypatch, dtype):
    fast = untangle_mod.orthomax_rotations(blob_fields, {0: 10}, restarts=2, seed=1, iteration_dtype=dtype)
    monkeypatch.setattr(untangle_mod, "horst", horst_mod.horst_batched)
    ref = untangle_mod.orthomax_rotations(blob_fields, {0: 10}, restarts=2, seed=1, iteration_dtype=dtype)
    # The same steps through other kernels (the batched path's products can be wider): the
    # same step count, rotations to horst_roundoff (seen on AVX2 MKL at two threads: 2.6e-6
    # with the float32 phase, the bound 1.5e-3; 4.7e-14 in float64, the bound 8.7e-13).
    assert fast[0].iterations == ref[0].iterations
    y = (blob_fields.forms[:, :10].double() * blob_fields.system.mass.double().sqrt()[:, None])[None]
    a = ref[0].rotation[None, None]
    bound = float(horst_roundoff(y, a, torch.tensor([[ref[0].iterations]]), dtype))
    diff = fast[0].rotation - ref[0].rotation
    assert float(diff.abs().max()) <= bound
    # Objectives f = Σ (Y A)^4: the kept one moves by at most 4 |G| |ΔA| (G = Yᵀ (Y A)^3, its
    # gradient) plus the evaluation's round-off (E n terms); every restart's within that
    # first-order bound on the rotations' bound, 4 n bound relative (f = <A, G> ~ |G|).
    g = horst_mod.Products(y, 1, torch.float64)(a)
    moved = 4 * float(g.norm()) * float(diff.norm()) + y.shape[1] * 10 * EPS64 * ref[0].score
    assert abs(fast[0].score - ref[0].score) <= moved
    torch.testing.assert_close(fast[0].restart_scores, ref[0].restart_scores, rtol=4 * 10 * bound, atol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_untangle_is_the_same_with_either_gradient(monkeypatch, dtype):
    """The moments only replace the float64 steps' products (after the float32 phase, or all
    of them with iteration_dtype=float64): the same iterations, rotations and objective to
    round-off."""
    s = shapes.three_blobs()
    fields = ta.akvf(ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)]), n=12)

    def run(moments: bool, tol: float):
        monkeypatch.setattr(untangle_mod, "fourth_moments_pay", lambda e, n, steps: moments)
        return untangle_mod.untangle(fields, restarts=3, seed=2, iteration_dtype=dtype, tol=tol)
    # Step counts are discrete: the two ways' stopping values (trace(D)) differ by ~1e-13
    # relative, so their counts agree wherever no stopping test lies within that of tol. Which
    # tolerances are clear of every stopping test depends on the CPU's float32 phase (on an AMD
    # EPYC's AVX2 kernels one lay within 1e-3 of 0.999e-6), so the comparison is made at the
    # first of a few tolerances where the products' way gives the same counts at tol x (1 ± 1e-3):
    # no stopping test lies within 1e-3 of it there, 1e10 times the two ways' difference.
    for tol in (1e-6, 0.7e-6, 1.4e-6):
        want = run(False, tol)
        if all(torch.equal(run(False, tol * f).iterations, want.iterations) for f in (1 - 1e-3, 1 + 1e-3)):
            break
    else:
        pytest.fail("every tolerance tried lies within 1e-3 of a stopping test")
    got = run(True, tol)
    assert torch.equal(got.iterations, want.iterations)
    # The float32 phase is the same calls either way; the float64 steps sum the same products
    # in another order: rotations to horst_roundoff, the objective to 4 |G| |ΔA| (its gradient
    # times the move) plus its evaluation's round-off (E n terms).
    y = (fields.forms[:, :12].double() * fields.system.mass.double().sqrt()[:, None])[None]
    a = want.rotation.double()[:, None]
    diff = got.rotation.double() - want.rotation.double()
    assert float(diff.abs().max()) <= float(horst_roundoff(y, a, want.iterations[:, None], torch.float64))
    g = horst_mod.Products(y, 1, torch.float64)(a)
    moved = 4 * float(g.norm()) * float(diff.norm()) + y.shape[1] * 12 * EPS64 * float(want.score)
    assert float((got.score - want.score).abs().max()) <= moved


# ---- float32 iterations against float64 ------------------------------------------------------
# The defaults use float32 for the large products only, then float64 iterations to the end;
# every choice between results is made in float64. What must hold on any BLAS, thread count or
# padding: the float32 path ends on a float64 stationary point (one more float64 step gains less
# than the stopping tolerance) whose objective equals the float64 path's to within the spread of
# competing optima; on three_blobs (three distinct blobs) every field lives on one blob and each
# blob gets the same span of fields (its degenerate eigenvalue pairs let rotations inside one blob
# compete). Where optima compete (the bent dumbbell, exactly symmetric shapes) which one is
# reached may depend on round-off, so fields are not compared there. "Another machine" is
# simulated by one thread and by perturbing the inputs at float32's rounding level (1e-7
# relative).

N = 16       # the fields of blobs_and_bent_float64 (conftest)
TOL = 1e-6   # untangle's default stopping tolerance (relative change per iteration)
#: The objective may still rise after the stopping test (measured on the bent dumbbell: 1.2e-5
#: between tol 1e-6 and 1e-7); competing optima on these shapes differ by ~5e-6.
SCORE_RTOL = 100 * TOL


def _jittered(fields, rel: float, seed: int):
    g = torch.Generator().manual_seed(seed)
    out = ta.AKVFResult(**{k: getattr(fields, k) for k in fields.__dataclass_fields__})
    out.forms = fields.forms * (1 + rel * torch.randn(fields.forms.shape, generator=g, dtype=fields.forms.dtype))
    return out


def _float32_variants(fields):
    yield "default", fields, None
    yield "one thread", fields, 1
    yield "inputs jittered 1e-7", _jittered(fields, 1e-7, seed=1), None


def _one_float64_step_gain(unt) -> torch.Tensor:
    """[B] relative objective gain of one more float64 Horst step from the returned rotations."""
    fields = unt.source
    y = fields.forms[:, :N].double() * fields.system.mass.double().sqrt()[:, None]
    ypad, _ = pad_packed(y, fields.batch.edge_ptr)
    a = unt.rotation.double()[:, None]                                     # [B, 1, n, n]
    before = untangle_mod.orthomax_objective(ypad, a)[:, 0]
    stepped, _ = horst_mod.horst(ypad, a, tol=0.0, max_iter=1, iteration_dtype=torch.float64)
    after = untangle_mod.orthomax_objective(ypad, stepped)[:, 0]
    return (after - before) / before


def test_untangle_float32_iterations_reach_a_float64_optimum(blobs_and_bent, blobs_and_bent_float64):
    fields, reference = blobs_and_bent, blobs_and_bent_float64
    assert reference.rotation.shape[-1] == N
    assert (_one_float64_step_gain(reference) < 10 * TOL).all()
    for what, f, threads in _float32_variants(fields):
        saved = torch.get_num_threads()
        if threads:
            torch.set_num_threads(threads)
        try:
            b = ta.untangle(f, n=N, seed=0, iteration_dtype=torch.float32)
        finally:
            torch.set_num_threads(saved)
        assert b.rotation.dtype == torch.float64
        gain = _one_float64_step_gain(b)
        assert (gain < 10 * TOL).all(), (what, gain)       # a float64 stationary point
        rel = (b.score / reference.score - 1).abs()
        assert (rel < SCORE_RTOL).all(), (what, rel)
        # three_blobs: every field lives on one blob, and each blob gets the same span of fields.
        # Not the same fields: the blobs' eigenvalues come in degenerate pairs, so rotations
        # inside one blob's span compete (which one is reached depends on the BLAS: seen on
        # another CPU model, field cosines down to 0.74 at equal objective).
        _assert_same_blob_spans(reference, b, what)


def _blob_of_each_field(unt, blob_of_face: torch.Tensor) -> torch.Tensor:
    """[n] the blob holding most of each untangled field's squared norm on three_blobs (mesh 0);
    asserts that it holds nearly all of it (the field is localized)."""
    feats = unt.mesh_features(0).double() ** 2                                # [F, n]
    share = torch.stack([feats[blob_of_face == j].sum(0) for j in range(3)])  # [3, n]
    share = share / share.sum(0)
    assert share.max(0).values.min() > 0.99, share.max(0).values.min()
    return share.argmax(0)


def _assert_same_blob_spans(reference, other, what: str) -> None:
    feats = reference.mesh_features(0).double()[None]
    mask = torch.ones(feats.shape[:2], dtype=torch.bool)
    blob_of_face = spherical_kmeans(feats, mask, 3, seed=0, restarts=10).labels[0]
    ref_blob, other_blob = _blob_of_each_field(reference, blob_of_face), _blob_of_each_field(other, blob_of_face)
    for j in range(3):
        a = reference.rotation[0].double()[:, ref_blob == j]        # the blob's fields, in the eigenbasis
        c = other.rotation[0].double()[:, other_blob == j]
        assert a.shape[1] == c.shape[1] > 0, (what, j, a.shape[1], c.shape[1])
        # principal angles between the two orthonormal column sets: all cosines 1
        cosines = torch.linalg.svdvals(a.T @ c)
        assert cosines.min() > 1 - 1e-6, (what, j, cosines.min())


def test_host_synchronizations_per_untangling_step_have_a_ceiling():
    """Calls that would make the host wait for a GPU (tests/helpers/syncs.py) per Horst step of
    the batched untangling (two meshes, the device's path), counted on the CPU as the difference
    between 12 and 3 steps per phase (float32 then float64, tol 1e-30: no restart stops): the SVD
    of each step (torch reads its error code; the extrapolated step has a second one) and one
    read of the active restarts per SQUAREM cycle; no mask indexing, no nonzero."""
    from helpers.syncs import SyncCounter
    gen = torch.Generator().manual_seed(0)
    y = torch.randn(2, 300, 6, generator=gen, dtype=torch.float64)

    def counted(steps: int) -> SyncCounter:
        with SyncCounter() as counter:
            untangle_mod.orthomax(y, 3, 0, 1e-30, steps, torch.float32)
        return counter

    per = counted(12).counts - counted(3).counts
    steps = 2 * 9                                     # both phases
    assert per["linalg.svd"] == steps + steps // 3    # one per step, two per extrapolated step
    others = sum(per.values()) - per["linalg.svd"]
    assert others <= steps / horst_mod.SLOTS_EVERY, per


def _orthogonal(n: int, generator: torch.Generator) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=generator, dtype=torch.float64))
    return q


def test_moment_frame_turns_with_the_fields_and_so_does_the_untangling():
    """Another basis of the same span, Y B (B orthogonal, some signs flipped: what another
    eigensolver start returns inside an eigenspace), has the frame Bᵀ Q, signed by the
    statistics turned alike; started in it, the untangling ends on the same fields. Random
    forms, so nothing about a mesh makes it hold by accident."""
    gen = torch.Generator().manual_seed(5)
    e, n = 400, 6
    # a few edges carry each field much more than the rest: an untangling with an optimum
    y = torch.randn(e, n, generator=gen, dtype=torch.float64) * \
        (1.0 + 4.0 * (torch.rand(e, n, generator=gen, dtype=torch.float64) > 0.9))
    area = torch.rand(50, generator=gen, dtype=torch.float64)
    omega, radial = (torch.randn(50, n, generator=gen, dtype=torch.float64) for _ in range(2))
    b = _orthogonal(n, gen) * torch.tensor([1.0, -1.0, 1.0, -1.0, -1.0, 1.0], dtype=torch.float64)
    q = untangle_mod.moment_frame(y, (area, omega, radial))
    qb = untangle_mod.moment_frame(y @ b, (area, omega @ b, radial @ b))
    assert torch.allclose(q.T @ q, torch.eye(n, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(qb, b.T @ q, atol=1e-9), (qb - b.T @ q).abs().max()
    ends = []
    for yy, frame in ((y, q), (y @ b, qb)):
        a, score, _, _ = untangle_mod.orthomax(yy[None], 3, 0, 1e-12, 2000, torch.float64, frames=frame[None])
        ends.append(((yy @ a[0]) ** 2, float(score[0])))
    assert ends[0][1] == pytest.approx(ends[1][1], rel=1e-10)
    assert torch.allclose(ends[0][0], ends[1][0], atol=1e-6 * float(ends[0][0].max()))


def test_untangle_frame_is_checked(fields):
    with pytest.raises(ta.ParameterError, match="frame must be one of"):
        ta.untangle(fields, 4, frame="pca")
