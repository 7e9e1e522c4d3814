"""Dense and sparse kernels of the block Krylov solver (:mod:`.krylov`), on bases stored as
rows ([k, E]): S-orthonormalization, one Gram-Schmidt pass, products with R.

Rows, not columns: the Gram-Schmidt products are then plain row-major GEMMs, several times
faster than on column slices of an [E, k] array (they are memory-bound and dominate the cost
after the solves)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

from ..threads import single_threaded

#: Relative S-norm below which a new direction is numerically inside the basis and dropped.
DEPENDENT = 1e-10


def orthonormal(w: torch.Tensor, basis: torch.Tensor, mass: torch.Tensor):
    """S-orthonormal rows spanning w's [p, E] directions outside span(basis) [k, E], and b with
    ``w ≈ bᵀ @ out`` (components inside span(basis) are assumed already removed).

    Directions with relative S-norm below DEPENDENT are dropped (out has p' <= p rows).
    """
    gram = mm(w * mass, w.T)
    gram = 0.5 * (gram + gram.T)
    with single_threaded():
        g, u = torch.linalg.eigh(gram)
    top = float(g[-1].clamp(min=0))
    keep = g > (DEPENDENT ** 2) * max(top, 1e-300)
    if top <= 0 or not bool(keep.any()):
        return w[:0], w.new_zeros(0, w.shape[0])
    g, u = g[keep], u[:, keep]
    out = mm((u * g.rsqrt()).T, w)               # [p', E], S-orthonormal up to round-off
    if basis.shape[0] and int(keep.sum()) < len(keep):
        # Dropped directions were mostly round-off; what is left of them must not come back.
        out = out - mm(mm(out * mass, basis.T), basis)
    # Re-normalize (Cholesky-QR on a nearly orthonormal block).
    gram2 = mm(out * mass, out.T)
    gram2 = 0.5 * (gram2 + gram2.T)
    with single_threaded():
        chol = torch.linalg.cholesky(gram2)
        # L⁻¹ out as a product with the p×p inverse: gram2 is within round-off of I, so L is
        # as well conditioned, and a [p, p] x [p, E] product costs a third of the triangular
        # solve on [p, E] (0.1 against 0.33 ms at E = 45594).
        inverse = torch.linalg.solve_triangular(chol, torch.eye(len(chol), dtype=chol.dtype,
                                                                device=chol.device), upper=False)
    out = mm(inverse, out)
    # w = uᵀ-side: w = (√g u')ᵀ-combination of out0 = L out  =>  w ≈ (L diag(√g) uᵀ)ᵀ out.
    bmat = chol.T @ (g.sqrt()[:, None] * u.T)
    return out, bmat


def rowdot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[k] row-wise dot products of [k, E] arrays (through a [k, E] temporary: the einsum
    "ke,ke->k" that avoids it is several times slower)."""
    return (a * b).sum(1)


def project_out(w: torch.Tensor, wm: torch.Tensor, basis: torch.Tensor, chunk: int = 8):
    """One classical Gram-Schmidt pass: ``(w - c @ basis, c)`` with ``c = wm @ basisᵀ``
    (w, wm = w·S [p, E]; basis [m, E]; c [p, m]).

    Done CHUNK rows of the basis at a time, each chunk's coefficients and update back to back
    while its rows are in cache: the basis is then read from memory once, not twice (it is
    memory-bound: [136, 45594] is 50 MB; about half the time of the two whole-basis products).
    The coefficients are those of the two whole products (each a dot of wm with one row)."""
    m = basis.shape[0]
    if m <= chunk:
        c = mm(wm, basis.T)
        return w - mm(c, basis), c
    out = w.clone()
    coef = w.new_empty(w.shape[0], m)
    for s in range(0, m, chunk):
        rows = basis[s:s + chunk]
        c = mm(wm, rows.T)
        out.addmm_(c, rows, alpha=-1.0)
        coef[:, s:s + chunk] = c
    return out, coef


def stiffness_matrix(rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor, size: int):
    """R of one mesh for :func:`spmm` from its coalesced COO entries (sorted by row, then
    column, as :meth:`KillingSystem.block` gives them): a scipy CSR matrix on CPU (built
    without a sort), a torch CSR tensor elsewhere."""
    vals = vals.to(torch.float64)
    if rows.device.type == "cpu":
        crow = torch.zeros(size + 1, dtype=torch.int64)
        crow[1:] = torch.cumsum(torch.bincount(rows, minlength=size), 0)
        return sp.csr_matrix((vals.numpy(), cols.numpy(), crow.numpy()), shape=(size, size))
    return torch.sparse_coo_tensor(torch.stack([rows, cols]), vals, (size, size),
                                   check_invariants=False).to_sparse_csr()


def spmm(stiff, rows: torch.Tensor) -> torch.Tensor:
    """(R Xᵀ)ᵀ = X R for rows X [k, E] (R symmetric), as [k, E]."""
    if isinstance(stiff, sp.spmatrix):
        return torch.from_numpy(np.ascontiguousarray((stiff @ rows.numpy().T).T))
    return torch.sparse.mm(stiff, rows.T).T.contiguous()


def mm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a @ b, through torch's BLAS, whose threads follow ``torch.set_num_threads``.

    Not numpy's: the Gram-Schmidt shapes ([p, E] @ [E, m] and [p, m] @ [m, E], E ~ 10⁴-10⁵) are
    memory-bound, and numpy's OpenBLAS runs them on every core by default, which on a 2-core
    machine made the whole solve slower than on one thread (see docs/design.md). One thread
    each, torch's and numpy's products take about the same time here."""
    return a @ b
