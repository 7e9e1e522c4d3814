"""What two computations of one quantity by different kernels may differ by: batched against
one mesh, a fast path against its reference, another thread count, BLAS or CPU. Each bound is
derived from the problem's size and conditioning (standard round-off analysis, Higham's
*Accuracy and Stability of Numerical Algorithms*), so it tracks the problem instead of the
machine the test was written on, and stays orders of magnitude below what a real change
(another restart, another step count, a wrong index) moves the result by.

Bit-identity is asserted only where the same call runs on the same shapes (see the tests).
"""
from __future__ import annotations

import importlib

import numpy as np
import torch

EPS64 = float(torch.finfo(torch.float64).eps)
EPS32 = float(torch.finfo(torch.float32).eps)


def eps_of(dtype: torch.dtype) -> float:
    return float(torch.finfo(dtype).eps)


def horst_roundoff(y: torch.Tensor, a: torch.Tensor, iters: torch.Tensor,
                   iteration_dtype: torch.dtype) -> torch.Tensor:
    """[b, R] bound on the entries' difference of rotations a [b, R, n, n] reached by two
    computations of Horst's iteration on scaled forms y [b, E, n] after ``iters`` [b, R] steps.

    Per step: G = Yᵀ (Y A)^3 sums E rounded products (√E·eps relative to each column, eps of
    the products' dtype) and its float64 polar factor moves by n·eps64·κ, κ = σ_max/σ_min of
    G (the polar factor's sensitivity); the steps add at most linearly (the iteration
    contracts near its end point). Round-off seen: 20-700x below this on AVX2, AVX-512 and
    SSE kernels at one and two threads."""
    horst = importlib.import_module("torchakvf.fields.horst")
    y64 = y.to(torch.float64)
    g = horst.Products(y64, a.shape[1], torch.float64)(a.to(torch.float64))       # [b, R, n, n]
    s = torch.linalg.svdvals(g)
    kappa = s[..., 0] / s[..., -1].clamp_min(1e-300)
    e, n = y.shape[1], y.shape[2]
    per_step = e ** 0.5 * eps_of(iteration_dtype) + n * EPS64 * kappa
    return iters.to(torch.float64) * per_step


def residual_roundoff(system, vectors: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """[B, n] bound on the difference of two computations of the relative residuals
    (:func:`torchakvf.solvers.lobpcg.relative_residuals`) of packed ``vectors`` [ΣE, n].

    R w - λ S1 w cancels terms of size |R| |w| + |λ| S1 |w| row by row; each row's sum of a
    handful of them (at most 14 here: its nonzeros and the mass term) rounds by √14·eps ~ 4 eps
    of that size in any summation order, so the S1⁻¹-norm moves by at most 4 eps times the norm
    of the terms, over max(|λ|, 1) as the residual is."""
    from torchakvf.mesh.batch import owner_index
    owner = owner_index(system.edge_ptr.to(vectors.device))
    stiff = system.stiffness.coalesce()
    absolute = torch.sparse_coo_tensor(stiff.indices(), stiff.values().abs(), stiff.shape,
                                       check_invariants=False)
    terms = torch.sparse.mm(absolute, vectors.abs()) + system.mass[:, None] * vectors.abs() * values[owner].abs()
    size = vectors.new_zeros(values.shape).index_add_(0, owner, terms ** 2 / system.mass[:, None]).sqrt()
    return 4 * EPS64 * size / values.abs().clamp(min=1.0)


def assert_same_clustering(got, want, x: torch.Tensor, mask: torch.Tensor | None = None) -> None:
    """Two Lloyd runs (labels [B, N, R], cost [B, R], iterations [B, R], centers [B, R, k, d])
    of unit rows x [B, N, d] through different kernels: the same labels and iteration counts,
    costs to N·eps64 relative (a weighted sum of N terms) and centers (normalized means of at
    most N rows) to N·eps64. Labels are discrete: they are compared exactly because no row is
    within round-off of a tie, checked here on the final assignment (every row's best
    similarity beats its second by over 100 d·eps32, float32 similarities' round-off; rows
    outside ``mask`` [B, N], padding, left out)."""
    labels_g, cost_g, iters_g, centers_g = got
    labels_w, cost_w, iters_w, centers_w = want
    n_rows, d = x.shape[1], x.shape[2]
    if centers_w.shape[-2] > 1:
        sim = torch.einsum("bnd,brkd->bnrk", x.to(centers_w.dtype), centers_w)
        sim = sim.masked_fill((centers_w == 0).all(-1)[:, None], -torch.inf)     # padding centers
        top = sim.topk(2, dim=-1).values
        gap = top[..., 0] - top[..., 1]                                              # [B, N, R]
        if mask is not None:
            gap = gap[mask]
        assert float(gap.min()) > 100 * d * EPS32, float(gap.min())
    assert torch.equal(labels_g, labels_w)
    assert torch.equal(iters_g, iters_w)
    assert cost_g.dtype == cost_w.dtype and centers_g.dtype == centers_w.dtype
    torch.testing.assert_close(cost_g, cost_w, rtol=n_rows * EPS64, atol=n_rows * EPS64)
    torch.testing.assert_close(centers_g, centers_w, rtol=0, atol=n_rows * EPS64)


def labels_off_ties(got: np.ndarray, want: np.ndarray, similarity: np.ndarray, band: float) -> np.ndarray:
    """Indices of rows labelled differently by two computations (got, want [N]) where the row
    is not tied: its similarity [N, k] to the two labels' clusters differs by more than band.
    Empty where every disagreement is a near-tie that round-off may break either way."""
    differ = np.flatnonzero(got != want)
    gap = np.abs(similarity[differ, got[differ]] - similarity[differ, want[differ]])
    return differ[gap > band]


__all__ = ["EPS64", "EPS32", "eps_of", "horst_roundoff", "residual_roundoff", "assert_same_clustering",
           "labels_off_ties"]
