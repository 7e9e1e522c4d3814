"""Horst's gradient from Y's fourth moments (:mod:`torchakvf.fields.fourth_moments`): equal to
the two products' to round-off (padding rows, mesh subsets and several row passes included),
the same rotations, and the size rule."""
from __future__ import annotations

import importlib

import pytest
import torch
from helpers.forms import random_forms
from helpers.roundoff import horst_roundoff

untangle_mod = importlib.import_module("torchakvf.fields.untangle")


horst_mod = importlib.import_module("torchakvf.fields.horst")


fourth_moments_mod = importlib.import_module("torchakvf.fields.fourth_moments")


@pytest.mark.parametrize("n", [1, 2, 5, 12])
def test_moment_gradient_equals_the_products(n):
    y = random_forms(2, 700, n, seed=n)
    y[1, 500:] = 0                          # the second mesh padded to the first's rows
    gen = torch.Generator().manual_seed(10 + n)
    al = torch.stack([untangle_mod.random_rotations(3, n, gen) for _ in range(2)])   # [2, 3, n, n]
    got = fourth_moments_mod.FourthMoments(y)(al)
    want = horst_mod.Products(y, 3, torch.float64)(al)
    assert got.shape == want.shape == (2, 3, n, n) and got.dtype == torch.float64
    # Both sum the same 700·n³ products of four entries of y and three of A (|y| <= ~12,
    # |A| <= 1) in another order: the error is round-off of sums of that size. A wrong
    # multiplicity or index would be off by O(|G|).
    scale = float(torch.einsum("bei,bej->bij", y.abs(), y.abs() ** 3).max())
    assert float((got - want).abs().max()) <= 1e-13 * scale
    # a subset of the meshes (the batched path's live meshes; a batched product of another
    # batch size may round differently)
    sub = fourth_moments_mod.FourthMoments(y).select(torch.tensor([1]))
    assert float((sub(al[1:]) - got[1:]).abs().max()) <= 1e-13 * scale
    # a batch's pair products by index gathers (other devices' way) are the same products, bit
    # for bit: each is one rounded multiplication either way, into the same buffers, and the
    # Gram GEMMs that follow are the same calls on the same operands
    assert torch.equal(fourth_moments_mod.FourthMoments(y, gather=True).moments,
                       fourth_moments_mod.FourthMoments(y).moments)


@pytest.mark.parametrize("n", [3, 9, 32])
def test_moments_over_several_row_passes(n):
    """Rows taken in passes of up to 2048 (the last one partial) and every group of the
    quadruple blocks: each moment M_iklm (i any, k <= l <= m) equals the direct sum over rows."""
    y = random_forms(1, 4100, n, seed=20 + n)
    got = fourth_moments_mod.FourthMoments(y)
    k, l, m = got.triple_k, got.triple_l, got.triple_m
    want = torch.einsum("ei,ec->ic", y[0], y[0, :, k] * y[0, :, l] * y[0, :, m])
    mult = torch.where((k == l) & (l == m), 1.0, torch.where((k == l) | (l == m), 3.0, 6.0))
    scale = float((y[0].abs() ** 4).sum(0).max())
    assert got.moments.shape == (1, n, len(k))
    assert float((got.moments[0] - want * mult.double()).abs().max()) <= 1e-13 * 6 * scale
    # the pair products by index gathers (other devices' way): the same bits (as above)
    assert torch.equal(fourth_moments_mod.FourthMoments(y, gather=True).moments, got.moments)


def test_moment_steps_reach_the_products_rotations():
    """The whole float64 iteration (SQUAREM, restarts stopping at different steps) from the
    moments against the products: the same step counts and rotations equal to round-off."""
    y = random_forms(1, 900, 6, seed=4)
    gen = torch.Generator().manual_seed(5)
    a = torch.cat([torch.eye(6, dtype=torch.float64)[None], untangle_mod.random_rotations(3, 6, gen)])[None]
    tol = 1e-9
    got, got_iters = horst_mod.horst(y, a, tol, 500, torch.float64, moments=True)
    want, want_iters = horst_mod.horst(y, a, tol, 500, torch.float64, moments=False)
    # Step counts are discrete: equal where no stopping test lies within round-off of tol, as
    # the same counts at tol x (1 ± 1e-3) show (the two ways' trace(D) differ by ~1e-13
    # relative, 1e-4 of tol).
    assert torch.equal(got_iters, want_iters)
    for near in (tol * (1 - 1e-3), tol * (1 + 1e-3)):
        assert torch.equal(horst_mod.horst(y, a, near, 500, torch.float64, moments=False)[1], want_iters)
    assert len(set(want_iters[0].tolist())) > 1
    # Both sum the same products in another order: rotations to horst_roundoff (2e-14 seen).
    bound = horst_roundoff(y, want, want_iters, torch.float64)
    assert ((got - want).abs().amax(dim=(-2, -1)) <= bound).all()
    # the general (batched) path takes the moments too; its products can be wider (a stopped
    # restart keeps its slot until its cycle ends): round-off again (1e-14 seen on AVX2 MKL)
    batched, batched_iters = horst_mod.horst_batched(y, a, tol, 500, torch.float64, moments=True)
    assert torch.equal(batched_iters, got_iters)
    assert ((batched - got).abs().amax(dim=(-2, -1)) <= bound).all()


@pytest.mark.parametrize("e,n,steps,moments", [(45594, 32, 237, True), (14112, 32, 191, True),
                                               (6000, 32, 400, False), (6000, 24, 200, True),
                                               (6000, 16, 100, True), (45594, 32, 40, False),
                                               (500, 16, 200, False)])
def test_the_size_rule(e, n, steps, moments):
    """Where each way was measured faster (experiments/results/untangle_moments.md): the moments
    for long meshes, few fields and many steps (their one-time cost must be earned back), the
    products for short meshes with many fields."""
    assert fourth_moments_mod.fourth_moments_pay(e, n, steps) is moments
