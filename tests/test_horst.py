"""Horst's iteration (:mod:`torchakvf.fields.horst`): SQUAREM against a plain Horst iteration
written out here (the same optimum or a better one, in fewer steps), its extrapolation by hand,
the one-mesh CPU path against the batched one to round-off, and the gradient's choice."""
from __future__ import annotations

import importlib

import pytest
import torch
from helpers.forms import random_forms
from helpers.roundoff import horst_roundoff

import torchakvf as ta

untangle_mod = importlib.import_module("torchakvf.fields.untangle")


horst_mod = importlib.import_module("torchakvf.fields.horst")


def _problem(n: int, e: int, seed: int):
    """Scaled forms [1, e, n] made of n localized fields (each heavy on its own block of rows)
    mixed by a random rotation: a quartimax problem with a clear optimum, which plain Horst
    approaches slowly (linear convergence)."""
    gen = torch.Generator().manual_seed(seed)
    y = 0.3 * torch.randn(e, n, generator=gen, dtype=torch.float64)
    block = e // n
    for j in range(n):
        y[j * block:(j + 1) * block, j] += torch.rand(block, generator=gen, dtype=torch.float64)
    mix = untangle_mod.random_rotations(1, n, gen)[0]
    start = untangle_mod.random_rotations(1, n, gen)
    return (y @ mix)[None], torch.cat([torch.eye(n, dtype=torch.float64)[None], start])[None]


def _plain_horst(y: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int):
    """Textbook Horst for one start: A <- U Vᵀ of svd(Yᵀ (Y A)^3) until trace(D) changes by
    less than tol (relative). Returns (A, steps)."""
    d_old = -1.0
    for step in range(1, max_iter + 1):
        u, s, vh = torch.linalg.svd(y.T @ (y @ a) ** 3)
        a = u @ vh
        d = float(s.sum())
        if abs(d - d_old) < tol * abs(d):
            return a, step
        d_old = d
    return a, max_iter


def _objective(y: torch.Tensor, a: torch.Tensor) -> float:
    return float(((y @ a) ** 4).sum())


@pytest.mark.parametrize("n,e,seed", [(8, 800, 0), (12, 1200, 1), (16, 960, 2)])
def test_accelerated_horst_reaches_plain_horsts_optimum_in_fewer_steps(n, e, seed):
    y, a = _problem(n, e, seed)
    tol = 1e-8
    got, steps = horst_mod.horst(y, a, tol, 2000, torch.float64)
    for r in range(a.shape[1]):
        plain, plain_steps = _plain_horst(y[0], a[0, r], tol, 2000)
        ours = got[0, r]
        # orthogonal, at least as high an objective (up to the stopping tolerance), fewer steps
        assert torch.allclose(ours.T @ ours, torch.eye(n, dtype=torch.float64), atol=1e-12)
        assert _objective(y[0], ours) >= _objective(y[0], plain) * (1 - 10 * tol)
        assert int(steps[0, r]) < 0.8 * plain_steps, (int(steps[0, r]), plain_steps)
        # a stationary point of the plain iteration: one more step barely moves the objective
        more, _ = _plain_horst(y[0], ours, 0.0, 1)
        assert _objective(y[0], more) - _objective(y[0], ours) <= 10 * tol * _objective(y[0], ours)
        # the same rotated fields as plain Horst's, up to their order and signs (optima that
        # permute the fields have one objective; the extrapolation may land on another order)
        cos = (torch.nn.functional.normalize(y[0] @ ours, dim=0).T
               @ torch.nn.functional.normalize(y[0] @ plain, dim=0)).abs()
        best = cos.max(dim=1)
        assert sorted(best.indices.tolist()) == list(range(n))
        assert (best.values > 1 - 1e-4).all(), float(best.values.min())


def test_one_step_is_a_plain_horst_step():
    y, a = _problem(8, 800, 3)
    stepped, steps = horst_mod.horst(y, a, 0.0, 1, torch.float64)
    assert (steps == 1).all()
    for r in range(a.shape[1]):
        plain, _ = _plain_horst(y[0], a[0, r], 0.0, 1)
        assert torch.allclose(stepped[0, r], plain, atol=1e-12)


def test_extrapolated_point_by_hand():
    gen = torch.Generator().manual_seed(5)
    a0, a1, a2 = untangle_mod.random_rotations(3, 5, gen)
    r, v = a1 - a0, a2 - 2 * a1 + a0
    alpha = max(min(-float(r.norm() / v.norm()), -1.0), -horst_mod.SQUAREM_MAX_STEP)
    u, _, vh = torch.linalg.svd(a0 - 2 * alpha * r + alpha ** 2 * v)
    assert torch.allclose(horst_mod.extrapolated(a0, a1, a2), u @ vh, atol=1e-12)
    # |r| <= |v| gives α = -1: the point a0 + 2r + v = a2 itself
    assert torch.allclose(horst_mod.extrapolated(a0, a0 + 0.1 * (a2 - a0), a2), a2, atol=1e-12)


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
    # The batched path keeps a stopped restart's slot until its cycle ends (one host read per
    # cycle), so its products can be wider than the one-mesh path's: other GEMM kernels, other
    # round-off (AVX2 MKL: 4e-14 in float64, 6e-7 in float32), bounded by horst_roundoff.
    assert ((fast_a - ref_a).abs().amax(dim=(-2, -1)) <= horst_roundoff(y, ref_a, ref_iters, dtype)).all()
    # Step counts are discrete: equal where no stopping test lies within round-off of tol, as
    # the same counts at tol x (1 ± margin) show (round-off moves the relative change of trace(D)
    # by ~1e-7 with float32 products, 1% of tol; by < 1e-12 in float64, 1e-6 of tol).
    assert torch.equal(fast_iters, ref_iters)
    margin = 0.05 if dtype == torch.float32 else 1e-3
    for near in ((1 - margin) * tol, (1 + margin) * tol):
        assert torch.equal(horst_mod.horst_batched(y, a, near, 500, dtype)[1], ref_iters)
    assert fast_iters.dtype == ref_iters.dtype and fast_a.shape == ref_a.shape
    if r > 1:
        assert len(set(ref_iters[0].tolist())) > 1    # restarts stopped at different steps
    # the iteration cap, and the dispatch of horst for one CPU mesh
    capped, capped_iters = horst_mod.horst(y, a, tol, 3, dtype)
    ref_a, ref_iters = horst_mod.horst_batched(y, a, tol, 3, dtype)
    assert torch.equal(capped_iters, ref_iters) and (capped_iters == 3).all()
    assert ((capped - ref_a).abs().amax(dim=(-2, -1)) <= horst_roundoff(y, ref_a, ref_iters, dtype)).all()


fourth_moments_mod = importlib.import_module("torchakvf.fields.fourth_moments")


def test_the_moments_are_float64_steps():
    y = random_forms(1, 200, 4, seed=1)
    assert isinstance(horst_mod.horst_gradient(y, 9, torch.float64, True), fourth_moments_mod.FourthMoments)
    assert isinstance(horst_mod.horst_gradient(y, 9, torch.float64, False), horst_mod.Products)
    with pytest.raises(ta.TorchAKVFError):
        horst_mod.horst_gradient(y, 9, torch.float32, True)
