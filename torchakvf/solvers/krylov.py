"""Block shift-invert Krylov: the smallest eigenpairs of ``R w = λ S1 w`` of each mesh from one
CHOLMOD factor and block solves (several right-hand sides per triangular sweep).

Why this and not ARPACK or LOBPCG (see docs/design.md):

* A triangular solve with CHOLMOD is memory-bound: one sweep through the factor serves a block
  of right-hand sides almost as fast as one (2-3x cheaper per right-hand side at block 4-8).
  ARPACK applies the operator to one vector at a time.
* LOBPCG solves for every unconverged column at every iteration (≈ 10 x 48 solves on a PSB
  mesh); a Krylov space keeps every solve it made (≈ 3 solves per eigenpair, like ARPACK).
* Only the pairs that are asked for must converge (``need``): the extra pairs returned (room
  for spurious modes) need not, so the tiny gap after the last returned pair does not matter.

The shift: where the factor is an :class:`~torchakvf.solvers.factor.InteriorFactor`, σ lies
among the wanted eigenvalues (about 60% of them below it), so that they map to large |θ| on both
sides of 0 and the unwanted ones stay near 0: about 30% fewer solves than at σ below the
spectrum. Its result is checked: the pairs below σ must be exactly the eigenvalues its factor
counts there (inertia), every needed pair converged, else the mesh is solved again with its
definite factor (σ below the spectrum, :class:`~torchakvf.solvers.factor.ShiftedFactor`). Where
the factor also counted the spurious modes below ``skip_below`` (``InteriorFactor.skipped``),
the Ritz pairs below it are neither waited for nor returned, and the count checked is that of
[skip_below, σ): a mesh with many spurious modes does not make its wanted pairs wait for them.

Method, per mesh: with ``T = (R - σS)^{-1} S`` (S-self-adjoint; its eigenvalues are
``θ = 1/(λ - σ)``, and the wanted pairs are those with the smallest ``λ = σ + 1/θ``: the largest
θ for a definite σ), build an S-orthonormal basis Q of the block Krylov space
``span{T X0, T² X0, ...}`` with full reorthogonalization (two Gram-Schmidt passes), and the
projection ``M = Qᵀ S T Q``. A Ritz pair (θ, y) of M gives ``x = Q y``, ``λ = σ + 1/θ`` and
exactly (Krylov relation ``T Q = Q M + Q_next B Eᵀ``)

    (R - λ S) x = -(R - σS) Q_next B y_last / θ,

so each pair's residual costs a p×p Gram of ``(R - σS) Q_next``, no product with the whole
basis. When the needed pairs pass, the returned vectors' residuals are recomputed from R and
S (as in :func:`relative_residuals`), with their Rayleigh quotients as eigenvalues.
"""
from __future__ import annotations

import logging
import math
from typing import NamedTuple

import torch

from ..errors import FieldCountError, ParameterError
from ..operators.killing import KillingSystem
from ..threads import single_threaded
from .cholesky import contiguous_transpose
from .factor import mesh_factor
from .krylov_kernels import mm, orthonormal, project_out, rowdot, spmm, stiffness_matrix
from .lobpcg import EigenResult

log = logging.getLogger(__name__)

#: Right-hand sides per block solve. CHOLMOD's simplicial solve sweeps the factor once per 4
#: right-hand sides (4 columns cost about 1.5x one, 5-8 about 2.7x), and 4 per step needs the
#: fewest solves per converged pair (see docs/design.md).
BLOCK = 4
#: A block-p Krylov space holds at most p copies of a repeated eigenvalue (in exact arithmetic;
#: the irreducible representations of the finite symmetry groups of a surface have dimension
#: <= 5, icospheres have 5-fold eigenvalues). Where p of the returned eigenvalues crowd within
#: _CROWDED of each other, the mesh is solved again with WIDE_BLOCK right-hand sides per step
#: (the same two sweeps through the factor as 6), which holds 8 copies.
WIDE_BLOCK = 8
#: Relative spread (to max(|λ|, 1)) of p eigenvalues that counts as a possible repeated one;
#: generous: a false alarm costs one more solve, a missed copy would be a wrong answer.
_CROWDED = 1e-3
#: A needed pair counts as converged when its estimated residual is below this fraction of tol
#: (the estimate is exact up to round-off; the margin absorbs that round-off).
_SAFETY = 0.9
#: Squared norm fraction left after one Gram-Schmidt pass below which a second pass is made.
_REORTH = 0.5


class KrylovBasis(NamedTuple):
    """How :func:`block_krylov` sizes its basis.

    block : right-hand sides per solve; max_dim : largest basis before giving up on a mesh
        (None: ``max(10 count, 240)``), capped at the mesh's edge count; grow : return more than
        ``count`` pairs where the needed ones reach beyond it (the room past them stays
        ``count - need``); one mesh only, since meshes then differ in the number of pairs
    """
    block: int = BLOCK
    max_dim: int | None = None
    grow: bool = False


def block_krylov(system: KillingSystem, count: int, tol: float = 1e-6, seed: int = 0,
                 names: list[str] | None = None, need: int | None = None,
                 skip_below: float | None = None, basis: KrylovBasis = KrylovBasis(),
                 factors: list | None = None, meshes: list[int] | None = None) -> EigenResult:
    """The ``count`` smallest eigenpairs of every mesh of ``system``, one mesh at a time.

    meshes : solve only these meshes of the system (indices, in that order; default all), so
        a subset needs no :meth:`KillingSystem.select`; names and factors then follow it

    count : pairs returned per mesh
    need : pairs that must reach ``tol`` (the first ``need`` in ascending order; default
        ``count``). With ``skip_below``, pairs whose value is below it (spurious modes) do not
        count towards ``need`` (the first ``need`` pairs at or above it, and every pair below
        them, must converge); the others are returned as they are, residuals included.
    basis : a :class:`KrylovBasis` (block width, largest basis, grow). A mesh that does not
        converge within the largest basis is returned with ``converged`` False and a warning. A
        mesh with more pairs below ``skip_below`` than ``count - need`` is returned as soon as
        that shows (residuals inf, without a warning): its caller must solve it again with a
        larger count, unless ``basis.grow``
    seed : the start block of each mesh is ``torch.Generator().manual_seed(seed)`` alone, so a
        mesh gets the same result in any batch
    factors : optional precomputed :class:`ShiftedFactor` per mesh

    Returns an :class:`EigenResult`; ``iterations`` counts shift-invert right-hand sides;
    ``left_out`` the pairs below ``skip_below`` that an interior factor counted (its
    ``skipped``), which were then neither waited for nor returned (0 for any other factor).
    """
    block, max_dim, grow = basis
    meshes = list(range(system.n_meshes)) if meshes is None else [int(b) for b in meshes]
    nb = len(meshes)
    names = names or [f"mesh {b}" for b in meshes]
    need = count if need is None else min(need, count)
    sizes = (system.edge_ptr[1:] - system.edge_ptr[:-1]).tolist()
    for j, b in enumerate(meshes):
        if count > sizes[b]:
            raise FieldCountError(f"{names[j]}: {count} fields asked for but the mesh has only "
                              f"{sizes[b]} edges; ask for fewer fields")
    if grow and nb != 1:
        raise ParameterError(f"block_krylov(basis=KrylovBasis(grow=True)) solves one mesh at a time, got {nb}")
    values, vectors, residuals, solves, shifts, skipped, converged = [], [], [], [], [], [], []
    for j, b in enumerate(meshes):
        r, c, v, size = system.block(b)
        lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        mass = system.mass[lo:hi].to(torch.float64)
        factor = factors[j] if factors is not None else mesh_factor(system, b, names[j])
        stiff = stiffness_matrix(r, c, v, size)
        dims = (lambda k: max_dim) if max_dim else (lambda k: max(10 * k, 240))

        def solve(factor):
            leave_out = _leaves_out(factor, skip_below)
            lam, x, res, k = _one_mesh(stiff, mass, factor, count, need, skip_below, tol, seed,
                                       block, dims, grow, leave_out)
            if block < WIDE_BLOCK and not bool(torch.isinf(res).all()) and crowded(lam, block):
                log.info("%s: %d eigenvalues within %.0e of each other at block %d; solving again "
                         "at block %d", names[j], block, _CROWDED, block, WIDE_BLOCK)
                lam, x, res, k2 = _one_mesh(stiff, mass, factor, count, need, skip_below, tol,
                                            seed, WIDE_BLOCK, dims, grow, leave_out)
                k += k2
            return lam, x, res, k

        lam, x, res, k = solve(factor)
        leave_out = _leaves_out(factor, skip_below)
        done = bool((res[:_must_converge(lam, need, skip_below, leave_out)] <= tol).all())
        if hasattr(factor, "definite"):
            # An interior shift (InteriorFactor): the pairs below it must be exactly the ν
            # eigenvalues its factor counts there (those in [skip_below, σ) where it counted the
            # spurious ones too), and every needed pair must have converged; else (or with an
            # eigenvalue where no definite shift exists) the mesh is solved again with its
            # positive definite factor.
            if leave_out:
                found = int(((lam < factor.sigma) & (lam >= skip_below)).sum())
                expected = factor.below - factor.skipped
            else:
                found, expected = int((lam < factor.sigma).sum()), factor.below
            ok = done and bool(lam[0] > factor.floor)
            if found != expected or not ok:
                log.info("%s: at the interior shift %g, %d pairs below it against %d eigenvalues "
                         "(inertia), converged %s; solving again at a definite shift", names[j],
                         factor.sigma, found, expected, ok)
                factor, leave_out = factor.definite(), False
                lam, x, res, k2 = solve(factor)
                k += k2
                done = bool((res[:_must_converge(lam, need, skip_below, leave_out)] <= tol).all())
        if not bool(torch.isinf(res).all()) and not done:
            log.info("%s: block Krylov stopped at a basis of %d with residual %.2e > tol %.1e",
                        names[j], k, float(res.max()), tol)
        values.append(lam), vectors.append(x), residuals.append(res), converged.append(done)
        solves.append(k), shifts.append(factor.sigma), skipped.append(factor.skipped if leave_out else 0)
    dev = system.mass.device
    vals, res = torch.stack(values).to(dev), torch.stack(residuals).to(dev)
    return EigenResult(eigenvalues=vals, vectors=torch.cat(vectors).to(dev), residuals=res,
                       iterations=torch.tensor(solves, dtype=torch.long, device=dev),
                       shifts=torch.tensor(shifts, dtype=torch.float64, device=dev),
                       converged=torch.tensor(converged, device=dev),
                       left_out=torch.tensor(skipped, dtype=torch.long, device=dev))


def _leaves_out(factor, skip_below: float | None) -> bool:
    """Whether the solve with ``factor`` leaves the spurious pairs (below ``skip_below``) out:
    an :class:`~torchakvf.solvers.factor.InteriorFactor` that counted them by inertia."""
    return skip_below is not None and getattr(factor, "skipped", None) is not None


def _must_converge(lam: torch.Tensor, need: int, skip_below: float | None, leave_out: bool) -> int:
    """How many leading pairs of ``lam`` (ascending) must converge: the first ``need`` where
    the spurious pairs were left out, else :func:`_needed`."""
    return min(need, len(lam)) if leave_out else _needed(lam, need, skip_below)


def crowded(lam: torch.Tensor, p: int) -> bool:
    """Whether some p of the eigenvalues lam (ascending) lie within _CROWDED · max(|λ|, 1)."""
    if p < 2 or len(lam) < p:
        return False
    spread = lam[p - 1:] - lam[:len(lam) - p + 1]
    return bool((spread <= _CROWDED * lam[p - 1:].abs().clamp(min=1.0)).any())


def _needed(lam: torch.Tensor, need: int, skip_below: float | None) -> int:
    """How many leading pairs (ascending ``lam``) must converge: ``need`` plus the spurious ones
    below ``skip_below`` among them (capped at len(lam))."""
    if skip_below is None:
        return min(need, len(lam))
    ok = torch.cumsum((lam >= skip_below).to(torch.long), 0)
    reach = torch.nonzero(ok >= need).reshape(-1)
    return int(reach[0]) + 1 if len(reach) else len(lam)


def _one_mesh(stiff, mass, factor, count, need, skip_below, tol, seed, p, max_dim, grow,
              leave_out=False):
    """(λ [k], x [E, k], residuals [k], right-hand sides solved) for one mesh; k = count, or
    with ``grow`` as many as the needed pairs reach when spurious ones fill the room. With
    ``leave_out`` the Ritz pairs below ``skip_below`` are neither returned nor waited for: the
    k returned are the first at or above it (the first ``need`` of them converged).

    The basis is stored as rows (q [cap, E]; blocks [p, E]; see :mod:`.krylov_kernels`)."""
    e = len(mass)
    dev, dt = mass.device, torch.float64
    sigma = factor.sigma
    # Ritz pairs in the order of λ, not of θ, where eigenvalues lie below the shift (θ < 0).
    order_by = sigma if getattr(factor, "below", 0) > 0 else None
    inv_s = 1.0 / mass
    cap = min(max_dim(count), e)
    q = torch.empty(cap, e, dtype=dt, device=dev)
    hmat = torch.zeros(cap, cap, dtype=dt, device=dev)   # M = Qᵀ S T Q (upper part filled)
    gen = torch.Generator().manual_seed(seed)
    k = count

    def apply_t(rows: torch.Tensor) -> torch.Tensor:             # T = (R - σS)^{-1} S on rows
        return factor.solve_rows(rows * mass)

    start = torch.randn(e, p, generator=gen, dtype=dt).to(dev)
    blk, _ = orthonormal(apply_t(start.T), q[:0], mass)
    solved = p
    filled = prev = next_check = 0
    last = None                                        # (basis size, worst estimate) at last check
    while True:
        if blk.shape[0] == 0:
            # The space is invariant (or exhausted): continue from fresh random directions.
            if filled >= cap:
                break
            fresh = torch.randn(e, p, generator=gen, dtype=dt).to(dev).T
            fresh = fresh - (fresh * mass) @ q[:filled].T @ q[:filled]
            blk, _ = orthonormal(fresh, q[:filled], mass)
            if blk.shape[0] == 0:
                break
        width = min(blk.shape[0], cap - filled)
        blk = blk[:width]
        s0, filled = filled, filled + width
        q[s0:filled] = blk
        if filled >= cap:
            break
        # Next block: T applied to the newest one, orthogonalized against the whole basis.
        w = apply_t(blk)
        solved += width
        basis = q[:filled]
        # First the newest two blocks (the block Lanczos recurrence: in exact arithmetic T Q_k
        # has no other components), which removes the bulk of w; then one pass against the
        # whole basis for the round-off that the recurrence lets grow. That pass sees no
        # cancellation, so it needs no repetition (checked: DGKS criterion), and it reads the
        # basis twice instead of the four times of two full Gram-Schmidt passes.
        near = q[prev:filled]
        coef = torch.zeros(w.shape[0], filled, dtype=dt, device=dev)
        local = mm(w * mass, near.T)
        w = w - mm(local, near)
        coef[:, prev:filled] = local
        wm = w * mass
        for _ in range(2):
            before = rowdot(wm, w)
            w, again = project_out(w, wm, basis)
            coef += again
            wm = w * mass
            if bool((rowdot(wm, w) > _REORTH * before).all()):
                break
        prev = s0
        hmat[:filled, s0:filled] = coef.T
        blk, bmat = orthonormal(w, basis, mass)          # w = bmatᵀ @ blk
        if filled < max(k + p, next_check):
            continue
        # Ritz pairs of the current basis and their exact residual estimate.
        theta, y = _ritz(hmat[:filled, :filled], filled, order_by)
        lam = sigma + 1.0 / theta
        if leave_out:
            kept = lam >= skip_below
            theta, y, lam = theta[kept], y[:, kept], lam[kept]
            if len(lam) < k:
                continue
        nneed = need if leave_out else _needed(lam, need, skip_below)   # over every Ritz value
        if nneed > k:
            # More spurious modes (below skip_below) than room among the first k. Ritz values
            # are upper bounds of the eigenvalues, so that count can only grow with the basis.
            if not grow:
                y = y[:, :k]
                x = mm(y.T, q[:filled]).T
                return lam[:k], x, torch.full((k,), float("inf"), dtype=dt, device=dev), solved
            k = nneed + (count - need)
            new_cap = min(max_dim(k), e)
            if new_cap > cap:
                q = torch.cat([q, q.new_empty(new_cap - cap, e)])
                hmat = torch.nn.functional.pad(hmat, (0, new_cap - cap, 0, new_cap - cap))
                cap = new_cap
            if filled < k + p:
                continue
        theta, y, lam = theta[:k], y[:, :k], lam[:k]
        if blk.shape[0] == 0:
            est = torch.zeros_like(lam)
        else:
            z = spmm(stiff, blk) - sigma * mass * blk                       # ((R - σS) Q_next)ᵀ
            gz = mm(z * inv_s, z.T)
            u = bmat @ y[s0:filled]                                          # [p', k]
            est = (u * (gz @ u)).sum(0).clamp(min=0).sqrt() / theta.abs() / lam.abs().clamp(min=1.0)
        worst = float(est[:nneed].max())
        if worst <= _SAFETY * tol:
            lam_f, x, res = _final(stiff, mass, q[:filled], y)
            if bool((res[:_must_converge(lam_f, need, skip_below, leave_out)] <= tol).all()):
                return lam_f, x, res, solved
        elif last is not None and 0 < worst < last[1]:
            # The residual falls about geometrically with the basis size: skip the checks
            # (an eigh of the whole projection each) until 80% of the predicted size, but
            # never past a quarter more basis (early rates are erratic).
            rate = math.log(last[1] / worst) / (filled - last[0])
            skip = 0.8 * math.log(worst / (_SAFETY * tol)) / rate
            next_check = filled + int(min(skip, 0.25 * filled))
        last = (filled, worst)
    # Out of room: the best the basis has.
    theta, y = _ritz(hmat[:filled, :filled], filled if leave_out else k, order_by)
    if leave_out:
        kept = torch.nonzero(sigma + 1.0 / theta >= skip_below).reshape(-1)[:k]
        theta, y = theta[kept], y[:, kept]
    lam_f, x, res = _final(stiff, mass, q[:filled], y)
    return lam_f, x, res, solved


def _ritz(m: torch.Tensor, count: int, sigma: float | None = None):
    """The ``count`` eigenpairs (θ, y) of the projection M (whose upper triangle is the
    computed one; the lower is its transpose in exact arithmetic) with the smallest λ = σ + 1/θ:
    the largest θ, in descending order, for a shift below the spectrum (``sigma`` None); for an
    interior shift ``sigma``, ascending λ (the θ < 0 first, most negative θ last among them)."""
    m = torch.triu(m) + torch.triu(m, 1).T
    with single_threaded():
        theta, y = torch.linalg.eigh(m)
    k = min(count, len(theta))
    if sigma is None:
        return theta.flip(0)[:k], y.flip(1)[:, :k]
    order = torch.argsort(sigma + 1.0 / theta)[:k]
    return theta[order], y[:, order]


def _final(stiff, mass, basis, y):
    """Ritz vectors x = basisᵀ y ([E, k] from basis [m, E] and y [m, k]; S-orthonormal: the
    basis and the projection's eigenvectors are) with their Rayleigh quotients λ (ascending)
    and residuals ||S^{-1/2}(R w - λ S w)|| / max(|λ|, 1) recomputed from R and S. (A
    Rayleigh-Ritz of (R, S) on span(x) would cost four more E·k² products for eigenvalues
    that are already accurate to the squared residual.)

    Worked on as rows (xr [k, E]): products and elementwise passes over row-major [k, E]
    arrays are several times faster here than over column slices of [E, k] ones."""
    xr = mm(y.T, basis)                                   # [k, E]
    rx = spmm(stiff, xr)                                  # (R x)ᵀ
    xm = xr * mass
    norm = rowdot(xm, xr)
    lam = rowdot(xr, rx) / norm
    order = torch.argsort(lam)
    if not bool((order == torch.arange(len(order), device=order.device)).all()):
        lam, xr, rx, xm, norm = lam[order], xr[order], rx[order], xm[order], norm[order]
    # In place from here (rx, xm and xr are this function's own [k, E] arrays): each fresh
    # [k, E] temporary is 15 MB of new pages at k = 40, E = 45594.
    res = rx.sub_(xm.mul_(lam[:, None]))                   # residual of the unnormalized x
    rel = (res.mul_(res).div_(mass).sum(1) / norm).sqrt() / lam.abs().clamp(min=1.0)
    return lam, contiguous_transpose(xr.mul_(norm.rsqrt()[:, None])), rel
